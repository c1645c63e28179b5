"""The study's control steps in C (``kernel.c``): built on first use with the machine's C compiler, cached by the
hash of the source and the flags, loaded with ``ctypes``.  ``load()`` returns the library, or None with the
reason in ``reason()`` (no compiler, a failed build, ``CLSAC_STUDY_KERNEL=numpy``): the study then steps in numpy,
with the same numbers (tests/tools/experiment/study/test_study_kernel.py flies both).

Why C: a step of the numpy loop is ~150 array operations of ~0.5 us of Python and numpy overhead each, whatever the
batch's width, so a batch of 24 aircraft over 60,000 steps (the long flights) paid ~100 us a step for ~2 us of
arithmetic.  The kernel does the same arithmetic with none of the overhead.

The flags are what keeps the numbers the numpy loop's, bit for bit: ``-ffp-contract=off`` (no fused multiply-add,
which GCC would otherwise use on CPUs that have it, e.g. aarch64) and no ``-ffast-math`` (no reassociation, IEEE
NaN and infinity rules)."""

from __future__ import annotations

import ctypes
import hashlib
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

SOURCE = Path(__file__).with_name("kernel.c")
FLAGS = ("-O2", "-std=c99", "-fPIC", "-shared", "-ffp-contract=off", "-fno-fast-math", "-fno-strict-aliasing")
ENV = "CLSAC_STUDY_KERNEL"  # "numpy": never build or load the kernel

_state: dict = {}


_i = ctypes.c_int64
_d = ctypes.c_double
_p = ctypes.POINTER(ctypes.c_double)
_q = ctypes.POINTER(ctypes.c_int64)


class Batch(ctypes.Structure):
    """kernel.c's ``Batch``, field for field (``load`` checks the size against the library's)."""

    _fields_ = [
        *((name, _i) for name in ("n", "steps", "hist_len", "window", "npeaks", "gust_width", "kind")),
        *((name, _i) for name in ("noisy", "dist", "turb_any", "gust_any", "aw", "freeze", "has_kmax")),
        *((name, _d) for name in ("umax", "sat_lim", "dz", "kmax", "dt")),
        ("coef", _p),
        ("law", _p),
        ("phi", _p),
        ("gam", _p),
        ("x", _p),
        ("dry", _p),
        ("xt", _p),
        *((name, _p) for name in ("turb", "bias", "noise", "thr", "crosswind")),
        ("delay", _q),
        ("g_first", _q),
        ("gust_k", _p),
        ("um_all", _p),
        ("hist", _p),
        *((name, _p) for name in ("y_prev", "u_fly", "u_prev")),
        ("acc", _p),
        ("wmax", _p),
        ("peaks", _p),
        ("rec", _p),
        *((name, _i) for name in ("tblock", "tblocks")),
        *((name, _d) for name in ("dev_ratio2", "dev_floor2", "ref_floor2", "follow_min", "hits_min", "rearm_lim")),
        ("nw", _d),
        *((name, _p) for name in ("tblk", "tring", "track", "hit_armed")),
        *((name, _d) for name in ("swing_h", "swing_tol", "swings_min", "dev_max2")),
        ("swing", _p),
        *((name, _i) for name in ("nphase", "ring_len")),
        *((name, _q) for name in ("ph_start", "ph_mat", "ph_jump", "ph_off", "ph_delay", "ph_reset")),
        *((name, _p) for name in ("ph_at", "mphi", "mgam", "ring", "ring_pos")),
        ("nsub", _i),
        ("sub_h", _d),
        ("ph_fine", _q),
        *((name, _p) for name in ("ph_rate", "mphi1", "mgam1", "mphic1")),
    ]


def _cache_dirs() -> list[Path]:
    """Beside the source (as Python's own bytecode cache), else a folder of this user's in the temp directory."""
    uid = os.getuid() if hasattr(os, "getuid") else "user"
    return [SOURCE.parent / "__pycache__", Path(tempfile.gettempdir()) / f"clsac-study-{uid}"]


def _compiler() -> str | None:
    return os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")


def _check_private(folder: Path) -> None:
    """A shared temp directory's folder is loaded from only if it is this user's and no one else can write to it
    (else another user could leave a library there for this process to load)."""
    if not hasattr(os, "getuid") or folder == SOURCE.parent / "__pycache__":
        return
    st = folder.stat()
    if st.st_uid != os.getuid() or st.st_mode & 0o022:
        raise OSError("not this user's own folder (owner or group/other write permission)")


def _build(cc: str) -> Path:
    """The shared library for this source and these flags: the cached one, else compiled now (written under a
    temporary name and renamed, so processes building at once never load a half-written file)."""
    digest = hashlib.sha256(SOURCE.read_bytes() + "\0".join((cc, *FLAGS)).encode()).hexdigest()[:16]
    name = f"study_kernel-{digest}{'.dll' if sys.platform == 'win32' else '.so'}"
    errors = []
    for folder in _cache_dirs():
        lib = folder / name
        if lib.exists():
            try:
                _check_private(folder)
            except OSError as exc:
                errors.append(f"{folder}: {exc}")
                continue
            return lib
        try:
            folder.mkdir(mode=0o700, parents=True, exist_ok=True)
            _check_private(folder)
            fd, tmp = tempfile.mkstemp(prefix=name + ".", dir=folder)
            os.close(fd)
        except OSError as exc:
            errors.append(f"{folder}: {exc}")
            continue
        try:
            r = subprocess.run([cc, *FLAGS, "-o", tmp, str(SOURCE), "-lm"], capture_output=True, text=True, timeout=120)
            if r.returncode != 0:
                raise OSError(f"{cc} failed: {(r.stderr.strip().splitlines() or ['?'])[-1]}")
            os.replace(tmp, lib)
            return lib
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)
    raise OSError("; ".join(errors) or "no folder to build in")


def load():
    """The kernel (a ``ctypes.CDLL`` with ``study_steps``), or None: then ``reason()`` says why.  Once per
    process."""
    if "lib" in _state:
        return _state["lib"]
    lib, why = None, ""
    if os.environ.get(ENV, "").lower() == "numpy":
        why = f"{ENV}=numpy"
    elif (cc := _compiler()) is None:
        why = "no C compiler (cc, gcc or clang; or CC)"
    else:
        try:
            lib = ctypes.CDLL(str(_build(cc)))
            lib.study_steps.argtypes = [
                ctypes.POINTER(Batch),
                ctypes.c_int64,
                ctypes.c_int64,
                ctypes.POINTER(ctypes.c_double),
            ]
            lib.study_steps.restype = None
            lib.study_batch_size.restype = ctypes.c_int64
            if lib.study_batch_size() != ctypes.sizeof(Batch):
                raise OSError(f"Batch is {lib.study_batch_size()} bytes in C, {ctypes.sizeof(Batch)} in Python")
        except (OSError, subprocess.SubprocessError, AttributeError) as exc:
            lib, why = None, f"the C kernel did not build or load ({exc})"
    _state["lib"], _state["reason"] = lib, why
    return lib


def reason() -> str:
    """Why ``load()`` gave None ("" when it gave the kernel)."""
    load()
    return _state["reason"]


def engine() -> str:
    """ "C kernel" or "numpy (<why>)", for the study's first line."""
    return "C kernel" if load() is not None else f"numpy ({reason()})"

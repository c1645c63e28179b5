"""Reading a plant file (``--plant FILE.toml``) from a careless or hostile hand: the bytes, the TOML and its keys.

What is read, and what is refused before anything is parsed (each in one line naming the file, ``PlantFileError``):

- only a regular file (a symlink to one is followed): a FIFO, a device (``/dev/zero``, a terminal), a socket or a
  folder is refused from its ``stat`` before it is opened, and it is opened non-blocking, so a FIFO swapped in
  between never blocks ``open()``;
- at most ``MAX_BYTES`` (1 MiB; the largest plant file, 50 states of double-precision ``A``, is about 60 kB): a
  larger file is refused from its size, and no more than that is ever read;
- UTF-8 TOML, nested at most as deep as Python's parser recurses (a ``RecursionError`` is a refusal);
- the tables and keys of the format (``KEYS``): an unknown key is refused with the closest known one, and a key of
  one table written in another (``den`` at the top level) is told where it goes.

No numerics here (``sitl.linear_plant`` checks the values).
"""

from __future__ import annotations

import os
import stat
import tomllib
from pathlib import Path

MAX_BYTES = 1 << 20  # a plant file's largest size (1 MiB)
MAX_NAME_CHARS = 100  # the plant's name is printed in every output: one short line

# The format, table by table (docs/plants.md); None: the top level.  [trim] is informative and free-form.
KEYS: dict[str | None, tuple[str, ...]] = {
    None: ("name", "description", "source", "input", "output", "airframe", "servo", "atmosphere", "trim"),
    "input": ("name", "unit", "surface", "limit", "rate_limit"),
    "output": ("name", "unit"),
    "airframe": ("states", "units", "A", "B", "C", "num", "den", "roll", "roll_rate", "yaw_rate", "side_velocity"),
    "servo": ("wn2", "two_zeta_wn"),
    "atmosphere": ("airspeed", "span", "altitude"),
}
TABLES = ("input", "output", "airframe", "servo", "atmosphere", "trim")


class PlantFileError(ValueError):
    """A plant file is unreadable or malformed; the message names the file and the offending key."""


_KINDS = (
    (stat.S_ISDIR, "a folder"),
    (stat.S_ISFIFO, "a FIFO"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
)


def _not_regular(mode: int) -> str | None:
    if stat.S_ISREG(mode):
        return None
    return next((name for test, name in _KINDS if test(mode)), "not a regular file")


def _refuse_unless_regular(path: Path, st: os.stat_result) -> None:
    kind = _not_regular(st.st_mode)
    if kind is not None:
        raise PlantFileError(f"{path}: not a plant file: it is {kind} (a plant file is a regular TOML file)")
    if st.st_size > MAX_BYTES:
        raise PlantFileError(f"{path}: {st.st_size} bytes, above the {MAX_BYTES} (1 MiB) a plant file may have")


def read_bytes(path: Path) -> bytes:
    """The file's bytes: a regular file of at most ``MAX_BYTES``, opened without blocking (see the module)."""
    try:
        _refuse_unless_regular(path, os.stat(path))
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_NOCTTY", 0) | getattr(os, "O_CLOEXEC", 0))
    except OSError as exc:
        raise PlantFileError(f"{path}: cannot read: {exc.strerror or exc}") from None
    try:
        _refuse_unless_regular(path, os.fstat(fd))  # what was opened, if it changed since the stat
        chunks, left = [], MAX_BYTES + 1
        while left > 0:
            chunk = os.read(fd, min(left, 1 << 16))
            if not chunk:
                break
            chunks.append(chunk)
            left -= len(chunk)
    except OSError as exc:
        raise PlantFileError(f"{path}: cannot read: {exc.strerror or exc}") from None
    finally:
        os.close(fd)
    data = b"".join(chunks)
    if len(data) > MAX_BYTES:  # it grew while being read
        raise PlantFileError(f"{path}: above the {MAX_BYTES} bytes (1 MiB) a plant file may have")
    return data


def read(path: Path) -> dict:
    """The parsed TOML document of a plant file, its keys checked against ``KEYS`` (values unchecked)."""
    data = read_bytes(path)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        raise PlantFileError(f"{path}: not a TOML plant file (not UTF-8 text)") from None
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise PlantFileError(f"{path}: not a TOML plant file: {exc}") from None
    except RecursionError:
        raise PlantFileError(f"{path}: not a TOML plant file: arrays or tables nested too deeply") from None
    check_keys(path, doc)
    return doc


def _where(table: str | None) -> str:
    return "at the top level" if table is None else f"in [{table}]"


def _home(key: str, here: str | None) -> str | None:
    """The table a key belongs to, if it is a key of another table than ``here``."""
    return next((t for t, keys in KEYS.items() if t != here and key in keys and t is not None), None)


def check_keys(path: Path, doc: dict) -> None:
    """Refuse a key the format does not have, naming where a misplaced one goes and the closest known one."""
    for table in (None, "input", "output", "airframe", "servo"):
        section = doc if table is None else doc.get(table)
        if not isinstance(section, dict):
            continue  # a missing table, or a value where a table belongs: said when the table is read
        for key in section:
            if key in KEYS[table]:
                continue
            home = _home(key, table)
            tf = [k for k in ("num", "den") if k in section]
            if table == "airframe" and len(tf) == 1:
                missing = "den" if tf == ["num"] else "num"
                raise PlantFileError(
                    f"{path}: [airframe] has {tf[0]} but no {missing} (and an unknown key {key!r}: misspelt?): a "
                    "transfer function needs both num and den under [airframe], highest power first"
                )
            if home is not None:
                why = f"{key} goes under [{home}]" + (" (a transfer function)" if key in ("num", "den") else "")
            else:
                import difflib  # only to name the key meant (difflib and heapq: not loaded by every flight)

                close = difflib.get_close_matches(key, KEYS[table], n=1)
                why = f"did you mean {close[0]}?" if close else f"the keys there are {', '.join(KEYS[table])}"
            raise PlantFileError(f"{path}: unknown key {key!r} {_where(table)}: {why}")


def table(path: Path, doc: dict, name: str, required: bool) -> dict:
    """The table ``[name]`` ({} if absent and not required)."""
    if name not in doc:
        if required:
            raise PlantFileError(f"{path}: no [{name}] table")
        return {}
    t = doc[name]
    if not isinstance(t, dict):
        got = f"{type(t).__name__} {t!r:.40}"
        raise PlantFileError(f"{path}: {name} must be a table ([{name}] with its keys), got {got}")
    return t


def text(path: Path, section: dict, where: str, key: str, default: str | None) -> str | None:
    """A one-line string value (at most ``MAX_NAME_CHARS``, no control characters), or ``default``."""
    if key not in section:
        return default
    v = section[key]
    if not isinstance(v, str):
        raise PlantFileError(f"{path}: {where} {key} must be a string, got {type(v).__name__} {v!r:.40}")
    if len(v) > MAX_NAME_CHARS or not v.isprintable():
        raise PlantFileError(
            f"{path}: {where} {key} must be one printable line of at most {MAX_NAME_CHARS} characters "
            f"(got {len(v)} characters)"
        )
    return v


def names(path: Path, section: dict, where: str, key: str, n: int, default: list[str]) -> list[str]:
    """A list of ``n`` one-line strings (``states``, ``units``), or ``default``."""
    if key not in section:
        return default
    v = section[key]
    if not isinstance(v, list) or len(v) != n or not all(isinstance(s, str) for s in v):
        got = f"{type(v).__name__} of {len(v)}" if isinstance(v, list) else f"{type(v).__name__} {v!r:.40}"
        raise PlantFileError(f"{path}: {where} {key} must be a list of {n} strings, one per state, got {got}")
    for s in v:
        text(path, {key: s}, where, key, None)
    return list(v)


__all__ = ["KEYS", "MAX_BYTES", "PlantFileError", "check_keys", "names", "read", "read_bytes", "table", "text"]

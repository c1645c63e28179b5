"""A flight's ``flight.png``: ``draw_flight_png``, and ``python -m tools.view.flight_picture``, the helper process that
draws it for the launcher, with ``PngHelper``, its client.

The picture is drawn with Pillow and numpy (``tools.view.flight_png``; it was matplotlib, whose import and first draw
cost about 0.75 CPU s).  ``Flight`` starts this helper together with a lockstep flight's three processes (a
real-time or pinned flight draws at the end instead: nothing is to take CPU from a loop on deadlines): it imports
numpy, PIL and the renderer (not the launcher's modules) while they start and fly, then waits.  When the flight has
ended the launcher sends it one request and joins the Rerun recording while the helper draws: two processes, two
cores.

The protocol, one line each way: the request on stdin is the JSON of the keywords of ``draw_flight_png``
(``tools.flight.files.png_request``); the answer on stdout is ``{"png": PATH or null}`` (null: no series to draw) or
``{"error": "TypeName: message"}`` (an OSError, ValueError or KeyError while drawing: the picture is missing, the
flight is not failed, as when the launcher drew it itself).  stdin closed without a request (a flight that ended
before it could draw, or ``png=False``): the helper exits 0 without drawing.  Anything else (a crash, no answer)
is for ``PngHelper.result`` to report: the launcher then draws the picture itself.
"""

from __future__ import annotations

import json
import math
import os
import select
import subprocess
import sys
from pathlib import Path

from tools.flight.children import child_env
from tools.view.series_files import load_series

EXPECTED = (OSError, ValueError, KeyError)  # what a picture may fail with without failing the flight
PNG_MAX_POINTS = 20_000  # flight.png plots every k-th step of a long flight: bounded memory whatever its length


def draw_flight_png(
    out: str | os.PathLike,
    name: str,
    lv: float,
    lockstep: bool,
    rate: float,
    u_limit_deg: float,
    metrics: dict,
    controller: str | None = None,
    plant: str = "KH2013A",
    surface: str = "rudder",
    surface2: str | None = None,
    law_label: str | None = None,
) -> Path | None:
    """DIR/flight.png from the flight's series (``tools.view.flight_png``); None without series.  ``plant``,
    ``surface``: named in the title and the command's panel, with ``surface2``, a square MIMO plant's second (the
    rudder: the title names both); the baseline's gains at the start and the parameters
    changed in flight come from the autopilot's stats (DIR/autopilot.json ``params_start``, ``param_changes``)."""
    from tools.view.flight_png import save_flight_png

    out = Path(out)
    series = load_series(out, max_points=PNG_MAX_POINTS)
    if not series or series.get("t") is None or not len(series["t"]):
        return None
    mode = "lockstep" if lockstep else "real time"
    surfaces = surface if not surface2 else f"{surface} and {surface2}"
    title = f"Flight {out.name}: {name} on {plant} ({surfaces}), {mode}, {rate:g} Hz"
    faults, changes = _stats(out, "sitl", "faults"), _stats(out, "autopilot", "param_changes")
    return save_flight_png(
        out / "flight.png",
        series,
        name=name,
        lv=lv,
        metrics=metrics,
        u_limit_rad=math.radians(u_limit_deg),
        title=title,
        controller=controller,
        law_label=law_label,
        faults=marks(faults, changes),
        surface=surface,
        gains=_start_gains(out),
        changes=changes,
    )


def _start_gains(out: Path) -> tuple[float, float, float] | None:
    """The baseline's K_p, K_i, K_d the flight started with (DIR/autopilot.json ``params_start``), or None."""
    try:
        with open(out / "autopilot.json") as f:
            start = json.load(f).get("params_start") or {}
        return tuple(float(start.get(f"PID_K{k}", start.get(f"CLSAC_PID_K{k}"))) for k in "PID")  # before: the alias
    except (OSError, ValueError, AttributeError, TypeError, KeyError):
        return None


def _stats(out: Path, process: str, key: str) -> list:
    """A list from a process's stats (DIR/sitl.json ``faults``, DIR/autopilot.json ``param_changes``); none without
    the file."""
    try:
        with open(out / f"{process}.json") as f:
            return list(json.load(f).get(key) or [])
    except (OSError, ValueError, AttributeError, TypeError):
        return []


def marks(faults, changes) -> list[tuple]:
    """flight.png's marks: (time, text) of each fault's start and end (sitl.json ``faults``) and (time, text, colour)
    of each parameter a ground station changed (autopilot.json ``param_changes``: "NAME from -> to")."""
    from tools.view.flight_png import C_PARAM

    return sorted([*fault_marks(faults), *((t, text, C_PARAM) for t, text in change_marks(changes))])


def change_marks(changes) -> list[tuple[float, str]]:
    """(time, "NAME from -> to") of each parameter a ground station changed (``summary.json`` ``param_changes``)."""
    return [
        (float(c["t_s"]), f"{c['name']} {c['from']:.4g} -> {c['to']:.4g}")
        for c in changes or ()
        if isinstance(c, dict) and c.get("t_s") is not None and c.get("from") is not None
    ]


def fault_marks(records) -> list[tuple[float, str]]:
    """(time, text) of the start and end of each fault that started (``summary.json`` / sitl.json ``faults``)."""
    out = []
    for f in records or ():
        if not isinstance(f, dict) or not f.get("started"):
            continue
        label = str(f.get("spec", f.get("kind", "fault"))).split("@")[0]
        out.append((float(f["start"]), f"fault {label}"))
        if f.get("end") is not None:
            out.append((float(f["end"]), f"end {label}"))
    return sorted(out)


def _warm_up() -> None:
    """Import what drawing needs: numpy, PIL and the renderer (no matplotlib), PIL's image formats, and zipfile (the
    series' .npz files)."""
    import zipfile  # noqa: F401

    from PIL import Image

    import tools.view.flight_png  # noqa: F401  (numpy, PIL's Image, ImageDraw and ImageFont)

    Image.preinit()  # the PNG writer's module, otherwise imported by the first save


def main() -> int:
    _warm_up()
    line = sys.stdin.readline()
    if not line.strip():
        return 0  # no request: nothing to draw
    request = json.loads(line)
    try:
        png = draw_flight_png(**request)
        answer = {"png": None if png is None else str(png)}
    except EXPECTED as exc:
        answer = {"error": f"{type(exc).__name__}: {exc}"}
    sys.stdout.write(json.dumps(answer) + "\n")
    sys.stdout.flush()
    # The launcher reads the answer line and goes on; tearing the modules down would only keep the process (and a
    # core) busy for longer.
    os._exit(0)


def helper_wanted(argv: list[str]) -> bool:
    """Whether ``python -m tools.launch ARGV`` flies a flight whose picture a helper draws (lockstep, with picture
    and series, not pinned), told from the words alone, before the launcher has imported what parses them: only the
    exact spellings count, so an abbreviated flag just means no early helper (``Flight`` starts one as before), and a
    helper that turns out not to be wanted is closed by ``Flight.start`` (``Flight.adopt_png_helper``)."""
    words = set(argv)
    if "--lockstep" not in words or words & {"-h", "--help", "--no-png", "--no-series", "--pin"}:
        return False
    return not any(w.startswith(("--no-png=", "--no-series=", "--pin=")) for w in words)


class PngHelper:
    """The helper process, started at once; ``request`` sends the one request, ``result`` waits for the answer."""

    def __init__(self):
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "tools.view.flight_picture"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,  # the answer; its warnings and errors go to the launcher's stderr, as before
            text=True,
            process_group=0,  # Ctrl-C reaches the launcher only, which still asks for the picture (children.py)
            env=child_env(PYTHONUNBUFFERED="1"),  # one OpenBLAS thread: the picture does no linear algebra
        )
        self._sent = False

    def request(self, request: dict) -> bool:
        """Send the request (once); False if the helper is gone (then draw in this process)."""
        if self._sent:
            raise RuntimeError("PngHelper: one request per helper")
        self._sent = True
        try:
            self.proc.stdin.write(json.dumps(request) + "\n")
            self.proc.stdin.close()
        except (BrokenPipeError, OSError, ValueError):
            return False
        return True

    def result(self, timeout_s: float = 120.0) -> tuple[bool, str | None, str | None]:
        """(answered, png path or None, error or None).  ``answered`` False: the helper crashed, said nothing
        readable or took longer than ``timeout_s`` (it is killed): the caller draws the picture itself."""
        line = ""
        if select.select([self.proc.stdout], [], [], timeout_s)[0]:
            line = self.proc.stdout.readline()  # the answer is one line written at once (or EOF: it crashed)
        try:
            answer = json.loads(line) if line.strip() else None
        except ValueError:
            answer = None
        if not isinstance(answer, dict):  # crashed (its traceback went to stderr), or silent too long
            self.close()
            return False, None, None
        return True, answer.get("png"), answer.get("error")

    def close(self) -> None:
        """End the helper: after its answer it exits by itself; without a request (or silent past the timeout) it
        is killed, it has nothing to keep."""
        requested = self._sent
        self._sent = True
        if self.proc.poll() is None:
            try:
                self.proc.wait(timeout=0.5 if requested else 0.0)  # after its answer it is exiting already
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        for f in (self.proc.stdin, self.proc.stdout):
            try:
                f.close()
            except (OSError, ValueError):
                pass


if __name__ == "__main__":
    sys.exit(main())

"""``python -m tools.flight.png``: the helper process that draws a flight's ``flight.png``; ``PngHelper``, its client.

Drawing the picture cost the launcher about 0.5 s after the flight, one thing after another: matplotlib's import
(about 0.25 s on the 2-core VM) and the first draw (mathtext's parser, the text layout).  So ``Flight`` starts this
helper together with the flight's three processes: it imports matplotlib and ``tools.plots`` while they start and
fly, then waits.  When the flight has ended the launcher sends it one request and joins the Rerun recording while
the helper draws: two processes, two cores.

The protocol, one line each way: the request on stdin is the JSON of ``tools.flight.files.png_request`` (the
keywords of ``draw_flight_png``); the answer on stdout is ``{"png": PATH or null}`` (null: no series to draw) or
``{"error": "TypeName: message"}`` (an OSError, ValueError or KeyError while drawing: the picture is missing, the
flight is not failed, as when the launcher drew it itself).  stdin closed without a request (a flight that ended
before it could draw, or ``png=False``): the helper exits 0 without drawing.  Anything else (a crash, no answer)
is for ``PngHelper.result`` to report: the launcher then draws the picture itself.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

EXPECTED = (OSError, ValueError, KeyError)  # what a picture may fail with without failing the flight


def _warm_up() -> None:
    """Import what drawing needs and build mathtext's parser (the first ``$...$`` label costs about 0.1 s)."""
    from matplotlib.mathtext import MathTextParser

    import tools.flight.files  # noqa: F401  (draw_flight_png)
    import tools.plots  # noqa: F401  (matplotlib's Figure and Agg canvas, tools.scenario)

    MathTextParser("agg").parse(r"$K_e$", 100)


def main() -> int:
    _warm_up()
    line = sys.stdin.readline()
    if not line.strip():
        return 0  # no request: nothing to draw
    request = json.loads(line)
    from tools.flight.files import draw_flight_png

    try:
        png = draw_flight_png(**request)
        answer = {"png": None if png is None else str(png)}
    except EXPECTED as exc:
        answer = {"error": f"{type(exc).__name__}: {exc}"}
    sys.stdout.write(json.dumps(answer) + "\n")
    sys.stdout.flush()
    return 0


class PngHelper:
    """The helper process, started at once; ``request`` sends the one request, ``result`` waits for the answer."""

    def __init__(self):
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "tools.flight.png"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            start_new_session=True,  # Ctrl-C reaches the launcher only, which still asks for the picture
            env=dict(os.environ, PYTHONUNBUFFERED="1"),
        )
        self._sent = False

    def request(self, request: dict) -> bool:
        """Send the request (once); False if the helper is gone (then draw in this process)."""
        if self._sent:
            raise RuntimeError("PngHelper: one request per helper")
        self._sent = True
        try:
            self.proc.stdin.write(json.dumps(request) + "\n")
            self.proc.stdin.flush()  # (kept open: ``communicate`` in ``result`` closes it)
        except (BrokenPipeError, OSError, ValueError):
            return False
        return True

    def result(self, timeout_s: float = 120.0) -> tuple[bool, str | None, str | None]:
        """(answered, png path or None, error or None).  ``answered`` False: the helper crashed, said nothing
        readable or took longer than ``timeout_s`` (it is killed): the caller draws the picture itself."""
        try:
            out, _err = self.proc.communicate(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            self.close()
            return False, None, None
        try:
            answer = json.loads(out.strip().splitlines()[-1]) if out.strip() else None
        except ValueError:
            answer = None
        if self.proc.returncode != 0 or not isinstance(answer, dict):
            return False, None, None
        return True, answer.get("png"), answer.get("error")

    def close(self) -> None:
        """End the helper: after its answer it has exited; without a request (or past the timeout) it is killed,
        it has nothing to keep."""
        self._sent = True
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
        for f in (self.proc.stdin, self.proc.stdout, self.proc.stderr):
            try:
                f.close()
            except (OSError, ValueError):
                pass


if __name__ == "__main__":
    sys.exit(main())

"""An internal error (a bug, not bad input): one line on the console, the traceback in the process's log file.

* Under the launcher (``tools.flight.children.Child`` sets ``LOG_ENV`` to the child's log file, DIR/autopilot.log,
  sitl.log or gcs.log), the process's output *is* that log, and the launcher echoes it to the console: the
  traceback goes out first as lines starting with ``"<prog>: traceback: "`` (:func:`is_traceback_line`), which the
  launcher writes to the log and does not echo, then the one line ``<prog>: error: Type: message (traceback in
  LOG)``, which it echoes and takes as the child's reason.
* A process given a log of its own (the launcher's DIR/launch.log): the traceback is appended to it.
* Run by hand: the traceback is written to ``<tmp>/<prog>-traceback-<pid>.txt`` and the one line names it.

If the traceback cannot be written (a full disk), the one line still goes out, without the "traceback in" part.
:func:`install` routes an exception nobody caught through the same path (``sys.excepthook``).
"""

from __future__ import annotations

import os
import sys
import tempfile
import traceback

LOG_ENV = "CLSAC_LOG_FILE"  # set by the launcher for each child: the file its output goes to
_MARK = ": traceback: "


def is_traceback_line(line: str, prog: str) -> bool:
    """Whether ``line`` (of ``prog``'s output) is a line of a traceback :func:`report` wrote for the log only."""
    return line.startswith(prog + _MARK)


def one_line(prog: str, exc: BaseException) -> str:
    """``<prog>: error: Type: message``, the message's lines joined."""
    text = " ".join(str(exc).split("\n"))
    return f"{prog}: error: {type(exc).__name__}" + (f": {text}" if text else "")


def report(prog: str, exc: BaseException, *, log: str | os.PathLike | None = None, file=None) -> str:
    """Report the internal error ``exc`` of ``prog`` (see the module's docstring); returns the one line printed.
    ``log``: the process's own log file to append the traceback to; ``file``: the console (default stderr)."""
    file = sys.stderr if file is None else file
    where = keep(prog, exc, log=log, file=file)
    line = one_line(prog, exc) + (f" (traceback in {where})" if where else "")
    print(line, file=file, flush=True)
    return line


def keep(prog: str, exc: BaseException, *, log: str | os.PathLike | None = None, file=None) -> str | None:
    """Keep the traceback of ``exc`` where the module's docstring says (never on a console); returns where, None if
    it could not be written.  (An error a process survives, a user's law that raised: ``autopilot.law``.)"""
    file = sys.stderr if file is None else file
    text = "".join(traceback.format_exception(exc))
    where = None
    try:
        if log is not None:
            with open(log, "a", encoding="utf-8") as f:
                f.write(text)
            where = str(log)
        elif os.environ.get(LOG_ENV):
            file.write("".join(f"{prog}{_MARK}{line}\n" for line in text.rstrip("\n").split("\n")))
            where = os.environ[LOG_ENV]
        else:
            fd, path = tempfile.mkstemp(prefix=f"{prog}-traceback-{os.getpid()}-", suffix=".txt")
            with os.fdopen(fd, "w", encoding="utf-8") as f:
                f.write(text)
            where = path
    except OSError:
        where = None  # nowhere to keep it (a full disk): the one line all the same
    file.flush()
    return where


def install(prog: str) -> None:
    """An exception nobody catches is reported by :func:`report` too; Ctrl-C (or the launcher's SIGINT) before the
    process took its own signal handlers is one line, ``<prog>: interrupted``, not a traceback of the import it
    cut (Python still ends the process by SIGINT)."""

    def hook(kind, exc, tb):
        if issubclass(kind, KeyboardInterrupt):
            print(f"{prog}: interrupted", file=sys.stderr, flush=True)
            return
        report(prog, exc if exc.__traceback__ is not None else exc.with_traceback(tb))

    sys.excepthook = hook

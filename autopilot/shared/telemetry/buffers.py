"""The rows a process queues for its telemetry writer, without rerun: ``Table``, ``NullTable``, ``StateChannel``.

The control loop appends here; the writer (``writer.Telemetry``) drains the queues on its own thread and hands the
rows to its sink (Rerun's streams, or a spool file that another process records, ``spool``).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable, Sequence

from autopilot.shared.telemetry.layout import Rgb, TableLayout


class Table:
    """The rows of one ``TableLayout``.  ``append`` is the only method the control loop calls."""

    __slots__ = ("layout", "_queue", "_push", "push", "handle", "__weakref__")

    def __init__(self, table_layout: TableLayout):
        self.layout = table_layout
        self._queue: deque = deque()
        self._push = self._queue.append
        #: Fastest form, no Python frame: ``push((sim_time_s, wall_time_s, values))`` (one tuple).
        self.push = self._queue.append
        self.handle = None  # what the writer's sink calls this table, once it has registered it

    def append(self, sim_time_s: float, wall_time_s: float, values: Sequence[float]) -> None:
        """Queue one row: sim time (s), wall clock (``time.time()``, s), values in ``layout.fields`` order.

        ``values`` must not be mutated afterwards (pass a tuple).  Never blocks, never calls rerun.
        """
        self._push((sim_time_s, wall_time_s, values))

    def __len__(self) -> int:
        return len(self._queue)


class NullTable:
    """What a disabled ``Telemetry`` hands out: appends cost a function call and do nothing."""

    __slots__ = ("layout",)

    def __init__(self, table_layout: TableLayout):
        self.layout = table_layout

    def append(self, sim_time_s: float, wall_time_s: float, values: Sequence[float]) -> None:  # noqa: ARG002
        return None

    def push(self, row: tuple) -> None:  # noqa: ARG002 - Table's signature, nothing kept
        return None

    def __len__(self) -> int:
        return 0


class StateChannel:
    """A discrete state (mode, failsafe) logged as ``StateChange`` plus a readable ``TextLog`` line.

    ``colors`` colour the states in the viewer; the text line of a state in ``warn`` is logged at WARN.
    """

    __slots__ = ("path", "label", "colors", "warn", "_queue", "last", "handle", "__weakref__")

    def __init__(self, path: str, label: str, colors: dict[str, Rgb] | None = None, warn: Iterable[str] = ()):
        self.path = path
        self.label = label
        self.colors = dict(colors or {})
        self.warn = frozenset(warn)
        self._queue: deque = deque()
        self.last: str | None = None
        self.handle = None  # what the writer's sink calls this channel, once it has registered it

    def set(self, sim_time_s: float, wall_time_s: float, state: str, note: str = "") -> bool:
        """Record a transition; repeated identical states are ignored.  Returns True if it was a change."""
        state = str(state)
        if state == self.last:
            return False
        self._queue.append((sim_time_s, wall_time_s, state, self.last, note))
        self.last = state
        return True

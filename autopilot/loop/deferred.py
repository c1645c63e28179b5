"""The lockstep autopilot's jobs after an answer (``AfterSend``): work that no peer waits for, run one job at a
time between two looks at the sockets, so that a frame arriving meanwhile is answered first (docs/design.md,
"Lockstep", the critical path).
"""

from __future__ import annotations

from collections import deque

# Jobs waiting at most; one more runs the oldest at once.  At 100 Hz with both streams at 10 Hz that is 40 frames: a
# loop that finds the next frame waiting every time (a loaded machine) still sends each stream within 0.4 s of sim.
AFTER_SEND_BOUND = 8


class AfterSend:
    """A bounded first-in first-out queue of jobs ``fn(*args)``.

    ``add`` queues a job whose arguments are the values it sends, taken when it was queued (so a job run a frame
    later sends what it would have sent at once); ``run_one`` runs the oldest; ``drain`` runs them all, in order.
    Nothing is dropped: when ``bound`` jobs wait, ``add`` first runs the oldest (``run_at_once`` counts those).
    ``queued`` counts every job, ``most`` is the longest the queue was, ``overtaken`` the reads of a socket that
    came before a waiting job (``LockstepScheduler._poll_or_job``)."""

    __slots__ = ("_jobs", "bound", "queued", "run_at_once", "most", "overtaken")

    def __init__(self, bound: int = AFTER_SEND_BOUND):
        if bound < 1:
            raise ValueError(f"the after-send queue needs room for a job, got bound {bound!r}")
        self._jobs: deque = deque()
        self.bound = bound
        self.queued = 0
        self.run_at_once = 0
        self.most = 0
        self.overtaken = 0

    def __len__(self) -> int:
        return len(self._jobs)

    def __bool__(self) -> bool:
        return bool(self._jobs)

    def add(self, fn, *args) -> None:
        jobs = self._jobs
        if len(jobs) >= self.bound:
            self.run_at_once += 1
            self.run_one()  # the oldest first: the order is kept
        jobs.append((fn, args))
        self.queued += 1
        if len(jobs) > self.most:
            self.most = len(jobs)

    def run_one(self) -> None:
        """Run the oldest job (it is off the queue before it runs: a job that raises is not run twice)."""
        fn, args = self._jobs.popleft()
        fn(*args)

    def drain(self) -> None:
        jobs = self._jobs
        while jobs:
            self.run_one()

    def summary(self) -> dict:
        return {
            "jobs": self.queued,
            "most_waiting": self.most,
            "run_at_once": self.run_at_once,
            "reads_before_a_job": self.overtaken,
        }

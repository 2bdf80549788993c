"""A clock task that runs slow jobs one at a time, so the task that hands them over does not
wait for them.

The scan loop hands a :class:`Worker` the work that can take time (re-reading recipes,
re-enabling drives, log updates) and picks up each :class:`Job`'s result at a later scan;
the cycle hands the camera's grab to one, so it can stop waiting when the grab hangs or the
cycle is cancelled. On the simulated clock a worker is a participant like any task, so the
simulation stays deterministic; on wall time it is a thread; on a single-threaded test clock
(:class:`~cell.clock.ManualClock`) a job runs at once, in the caller.
"""
from __future__ import annotations

from typing import Any, Callable

from cell.clock import Clock, ClockError
from cell.log import get_logger

log = get_logger("worker")


class Job:
    """One job: ``finished`` (a clock event) is set once ``result`` or ``error`` is in."""

    def __init__(self, clock: Clock, fn: Callable[..., Any], args: tuple):
        self.fn, self.args = fn, args
        self.finished = clock.event()
        self.done = False
        self.result: Any = None
        self.error: BaseException | None = None

    def outcome(self) -> Any:
        """The result; re-raises the job's exception."""
        if self.error is not None:
            raise self.error
        return self.result


class Worker:
    """Runs submitted jobs in order in one task named ``name`` of ``clock``."""

    def __init__(self, clock: Clock, name: str):
        self.clock, self.name = clock, name
        self._queue = clock.queue()
        self._task = None
        self._inline = getattr(clock, "single_threaded", False)
        self.busy_with: Job | None = None        #: the job running now, if any

    def start(self) -> None:
        if self._task is None and not self._inline:
            self._task = self.clock.spawn(self._run, self.name)

    def submit(self, fn: Callable[..., Any], *args: Any) -> Job:
        job = Job(self.clock, fn, args)
        if self._inline:
            self._do(job)
        else:
            self._queue.put(job)
        return job

    def run_here(self, fn: Callable[..., Any], *args: Any) -> Job:
        """Run a job in the calling task now (e.g. at start-up, before the scan runs)."""
        job = Job(self.clock, fn, args)
        self._do(job)
        return job

    def stop(self, timeout_s: float = 5.0) -> bool:
        """Let the queued jobs finish, then end the task; False if it did not end in time
        (a job hangs: the task is left behind, its thread is a daemon)."""
        if self._task is None:
            return True
        self._queue.put(None)
        return self._task.join(timeout=timeout_s)

    def _run(self) -> None:
        while True:
            job = self._queue.get()
            if job is None:
                return
            self._do(job)

    def _do(self, job: Job) -> None:
        self.busy_with = job
        try:
            job.result = job.fn(*job.args)
        except ClockError:
            raise                                      # the clock is going away: end the task
        except BaseException as exc:                   # noqa: BLE001 -- handed to whoever waits
            job.error = exc
        finally:
            self.busy_with = None
            job.done = True
            job.finished.set()

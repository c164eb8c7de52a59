"""Lanes: each lane's tasks in the order they were given, the lanes in parallel on a few
threads. For chains of work that release the GIL and meet only now and then (a run's rules:
each rule's maps are inserted into, fused and scored in order, and no rule waits for the
others at every exchange)."""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Callable, Hashable, Sequence
from concurrent.futures import Future

from .threads import ThreadBudget, budget_of


class Lanes:
    """Tasks per lane, in order; the ready task given first is run first (a lane that fell
    behind catches up). A task may also wait for tasks of other lanes (``after``). A task
    runs holding a slot of the budget ``threads`` (:class:`~octofuse.threads.ThreadBudget`,
    or a budget of that many threads): as many lanes run at once as the budget has free. With
    one thread every task runs at once, on the caller's thread.

    ``backlog`` bounds the tasks a lane holds: :meth:`submit` waits while its lane has that
    many. The first task to fail stops the others (queued tasks are dropped) and its error is
    raised by the next :meth:`submit` or :meth:`wait`. Use as a context manager: on leaving,
    the running tasks end and the threads stop (the queued ones are dropped if leaving on an
    error)."""

    def __init__(self, threads: int | ThreadBudget, backlog: int = 8):
        self.budget = budget_of(threads)
        self.backlog = max(1, backlog)
        self._cond = threading.Condition()
        self._queues: dict[Hashable, deque] = {}
        self._busy: set = set()
        self._seq = 0
        self._unfinished = 0
        self._error: BaseException | None = None
        self._closing = False
        self._threads = [
            threading.Thread(target=self._work, name=f"octofuse-lane-{k}", daemon=True)
            for k in range(self.budget.threads if self.budget.threads > 1 else 0)
        ]
        for t in self._threads:
            t.start()

    def submit(
        self, lane: Hashable, fn: Callable[[], object], after: Sequence[Future] = ()
    ) -> Future:
        """Run ``fn()`` after the lane's earlier tasks and the tasks ``after``; its future."""
        fut: Future = Future()
        if not self._threads:
            self._raise()
            try:
                with self.budget.working():
                    fut.set_result(fn())
            except BaseException as e:
                self._error = e
                raise
            return fut
        with self._cond:
            q = self._queues.setdefault(lane, deque())
            while len(q) >= self.backlog and self._error is None:
                self._cond.wait()
            self._raise()
            self._seq += 1
            q.append((self._seq, fn, tuple(after), fut))
            self._unfinished += 1
            self._cond.notify()
        return fut

    def wait(self) -> None:
        """Until every task given so far has ended; raises the first task's error."""
        with self._cond:
            while self._unfinished and self._error is None:
                self._cond.wait()
            self._raise()

    def close(self, drop: bool = False) -> None:
        """Stop the threads once their tasks are done (``drop``: the queued ones dropped)."""
        with self._cond:
            if drop:
                self._drop()
            self._closing = True
            self._cond.notify_all()
        for t in self._threads:
            t.join()

    def __enter__(self) -> Lanes:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close(drop=exc_type is not None)

    # -- internals --------------------------------------------------------------------------
    def _raise(self) -> None:
        if self._error is not None:
            raise self._error

    def _drop(self) -> None:
        for q in self._queues.values():
            for *_, fut in q:
                fut.cancel()
            self._unfinished -= len(q)
            q.clear()

    def _next(self):
        """The ready task given first (the caller holds the lock), or None."""
        best = None
        for lane, q in self._queues.items():
            if q and lane not in self._busy and all(f.done() for f in q[0][2]):
                if best is None or q[0][0] < self._queues[best][0][0]:
                    best = lane
        return best

    def _work(self) -> None:
        while True:
            with self._cond:
                while (lane := self._next()) is None:
                    if self._closing and not any(self._queues.values()):
                        return
                    self._cond.wait()
                _, fn, _, fut = self._queues[lane].popleft()
                self._busy.add(lane)
                self._cond.notify_all()  # room in the lane for a caller held back
            try:
                with self.budget.working():
                    result = fn()
                fut.set_result(result)
                failed = None
            except BaseException as e:  # handed to the caller, never lost on this thread
                fut.set_exception(e)
                failed = e
            with self._cond:
                self._busy.discard(lane)
                self._unfinished -= 1
                if failed is not None and self._error is None:
                    self._error = failed
                    self._drop()
                self._cond.notify_all()

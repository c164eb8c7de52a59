"""One thread budget for a run: at most ``threads`` threads at work at once, the caller's
thread, the threads it hands work to (:meth:`ThreadBudget.map`, :class:`~octofuse.lanes.Lanes`)
and the C++ core's (:meth:`ThreadBudget.core`) together. For work that releases the GIL
(calls into the C++ core, numpy on large arrays)."""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from typing import TypeVar

T = TypeVar("T")
R = TypeVar("R")


class ThreadBudget:
    """``threads`` slots (0: one per core), made once from the configuration and handed down.

    A thread holds a slot while it works for the budget: an item of :meth:`map`, a lane's
    task, a call into the core (:meth:`core`), each with the threads the core uses. A thread
    that holds none waits for one (:meth:`working`); a thread that holds one hands work only
    to the slots free at that moment and otherwise does it itself (inline). So the budget is
    never exceeded, and work started from work of the budget (nested calls) never waits for a
    thread that waits for it. Helper threads come from one pool, made on first use."""

    def __init__(self, threads: int = 0):
        from . import _core  # the core's count of the machine's threads, and its range

        if not 0 <= threads <= _core.MAX_THREADS:
            raise ValueError(
                f"threads = {threads}: expected 0 (one per core) to {_core.MAX_THREADS}"
            )
        self.threads = threads or _core.default_threads()
        self._free = self.threads
        self._cond = threading.Condition()
        self._local = threading.local()  # .held: this thread holds a slot
        self._pool: ThreadPoolExecutor | None = None

    # -- slots -------------------------------------------------------------------------------
    def take(self, n: int) -> int:
        """Up to ``n`` free slots, without waiting; the number taken (give them back)."""
        with self._cond:
            k = max(0, min(n, self._free))
            self._free -= k
            return k

    def give_back(self, n: int) -> None:
        if n:
            with self._cond:
                self._free += n
                self._cond.notify_all()

    @contextmanager
    def working(self) -> Iterator[None]:
        """The calling thread at work: holding a slot (waiting for one if it holds none)."""
        if getattr(self._local, "held", False):
            yield
            return
        with self._cond:
            while self._free <= 0:
                self._cond.wait()
            self._free -= 1
        self._local.held = True
        try:
            yield
        finally:
            self._local.held = False
            self.give_back(1)

    @contextmanager
    def core(self, at_most: int = 0) -> Iterator[int]:
        """The threads a call into the C++ core may use now: the calling thread's slot and
        the slots free (``at_most`` in all, if given), held until the call returns."""
        with self.working():
            extra = self.take((at_most or self.threads) - 1)
            try:
                yield 1 + extra
            finally:
                self.give_back(extra)

    # -- work ------------------------------------------------------------------------------
    def map(self, fn: Callable[[T], R], items: Iterable[T]) -> list[R]:
        """``[fn(x) for x in items]``, the results in order: on the calling thread and on as
        many free slots as there are items left (none free: all on the calling thread). The
        first error is raised once every thread has stopped."""
        items = list(items)
        with self.working():
            helpers = self.take(len(items) - 1) if len(items) > 1 else 0
            if not helpers:
                return [fn(x) for x in items]
            return self._spread(fn, items, helpers)

    def _spread(self, fn: Callable[[T], R], items: list[T], helpers: int) -> list[R]:
        """:meth:`map` on the calling thread and ``helpers`` slots taken for it."""
        results: list = [None] * len(items)
        state = {"next": 0, "error": None}
        lock = threading.Lock()

        def work() -> None:
            while True:
                with lock:
                    k = state["next"]
                    if k >= len(items) or state["error"] is not None:
                        return
                    state["next"] = k + 1
                try:
                    results[k] = fn(items[k])
                except BaseException as e:  # raised on the calling thread
                    with lock:
                        if state["error"] is None:
                            state["error"] = e
                    return

        def helper() -> None:
            self._local.held = True
            try:
                work()
            finally:
                self._local.held = False
                self.give_back(1)

        futures = [self._executor().submit(helper) for _ in range(helpers)]
        work()
        for f in futures:
            f.result()
        if state["error"] is not None:
            raise state["error"]
        return results

    def _executor(self) -> ThreadPoolExecutor:
        with self._cond:
            if self._pool is None:
                self._pool = ThreadPoolExecutor(
                    max_workers=max(1, self.threads - 1), thread_name_prefix="octofuse"
                )
            return self._pool

    def close(self) -> None:
        """Stop the pool's threads (made again if the budget is used after)."""
        with self._cond:
            pool, self._pool = self._pool, None
        if pool is not None:
            pool.shutdown()

    def __enter__(self) -> ThreadBudget:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def budget_of(threads: int | ThreadBudget) -> ThreadBudget:
    """``threads`` if it is a budget, else a budget of that many threads (0: one per core)."""
    return threads if isinstance(threads, ThreadBudget) else ThreadBudget(threads)


@contextmanager
def budget_scope(threads: int | ThreadBudget) -> Iterator[ThreadBudget]:
    """``threads`` if it is a budget (left open), else a budget of that many threads for the
    ``with`` block."""
    if isinstance(threads, ThreadBudget):
        yield threads
        return
    with ThreadBudget(threads) as budget:
        yield budget


def thread_map(fn: Callable[[T], R], items: Iterable[T], threads: int | ThreadBudget) -> list[R]:
    """``[fn(x) for x in items]`` on the budget ``threads`` (or a budget of that many, for
    this call)."""
    with budget_scope(threads) as budget:
        return budget.map(fn, items)

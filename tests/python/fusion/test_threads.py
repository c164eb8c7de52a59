"""One thread budget: never more threads at work than it holds, nested work inline, no
deadlock, errors reach the caller."""

from __future__ import annotations

import threading
import time

import pytest

from octofuse.lanes import Lanes
from octofuse.threads import ThreadBudget


class AtWork:
    """Counts the threads at work (a Python worker, or a thread the core was given) and
    keeps the most seen at once."""

    def __init__(self):
        self.now = self.most = 0
        self._lock = threading.Lock()

    def __call__(self, n: int = 1):
        outer = self

        class Span:
            def __enter__(self):
                with outer._lock:
                    outer.now += n
                    outer.most = max(outer.most, outer.now)

            def __exit__(self, *exc):
                with outer._lock:
                    outer.now -= n

        return Span()


def _run(fn, timeout: float = 60.0):
    """``fn()`` on a thread of its own; fails (instead of hanging) if it does not end."""
    out: dict = {}

    def target():
        try:
            out["value"] = fn()
        except BaseException as e:
            out["error"] = e

    t = threading.Thread(target=target, daemon=True)
    t.start()
    t.join(timeout)
    assert not t.is_alive(), "deadlock: the work did not end"
    if "error" in out:
        raise out["error"]
    return out["value"]


@pytest.mark.parametrize("threads", [1, 2, 3, 5])
def test_nested_maps_and_core_calls_stay_within_the_budget(threads):
    budget = ThreadBudget(threads)
    work = AtWork()

    def leaf(x):
        with budget.core() as n:  # what a call into the core would use
            assert 1 <= n <= threads
            with work(n):
                time.sleep(0.002)
        return x * x

    def middle(x):
        return sum(budget.map(leaf, range(x, x + 4)))

    def outer(x):
        return budget.map(middle, range(x, x + 3))

    with budget:
        got = _run(lambda: budget.map(outer, range(6)))
    want = [[sum(y * y for y in range(m, m + 4)) for m in range(x, x + 3)] for x in range(6)]
    assert got == want
    assert 1 <= work.most <= threads
    if threads > 1:
        assert work.most > 1  # the budget was used, not only the caller's thread


@pytest.mark.parametrize("threads", [1, 2, 4])
def test_lanes_and_their_nested_work_share_one_budget(threads):
    budget = ThreadBudget(threads)
    work = AtWork()
    seen = {lane: [] for lane in range(5)}

    def task(lane, i):
        def items(x):
            with budget.core(at_most=2) as n, work(n):
                time.sleep(0.001)
            return x

        assert budget.map(items, range(3)) == [0, 1, 2]
        seen[lane].append(i)

    def drive():
        with Lanes(budget, backlog=4) as lanes:
            for i in range(40):
                lanes.submit(i % 5, lambda i=i: task(i % 5, i))
            lanes.wait()
            # the caller's own calls meanwhile count too
            with budget.core() as n, work(n):
                pass

    with budget:
        _run(drive)
    assert seen == {lane: list(range(lane, 40, 5)) for lane in range(5)}
    assert 1 <= work.most <= threads


def test_the_first_error_of_a_map_reaches_the_caller():
    with ThreadBudget(3) as budget:

        def fn(x):
            if x == 5:
                raise ZeroDivisionError(x)
            return x

        with pytest.raises(ZeroDivisionError):
            _run(lambda: budget.map(fn, range(20)))
        # every slot was given back
        assert budget.take(4) == 3
        budget.give_back(3)
        assert _run(lambda: budget.map(lambda x: x, range(12))) == list(range(12))


def test_a_bad_thread_count_is_refused():
    from octofuse import _core

    with pytest.raises(ValueError, match=r"threads = -1: expected 0 \(one per core\) to 256"):
        ThreadBudget(-1)
    assert ThreadBudget(0).threads == _core.default_threads()

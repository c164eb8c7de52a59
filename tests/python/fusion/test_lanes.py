"""Lanes: each lane's tasks in order, lanes in parallel, dependencies across lanes, errors."""

from __future__ import annotations

import threading
import time

import pytest

from octofuse.lanes import Lanes


@pytest.mark.parametrize("threads", [1, 2, 3])
def test_each_lane_runs_its_tasks_in_order(threads):
    seen = {k: [] for k in range(4)}
    with Lanes(threads, backlog=3) as lanes:
        for i in range(40):
            lane = i % 4
            lanes.submit(
                lane, lambda lane=lane, i=i: (time.sleep(0.001 * (lane == 0)), seen[lane].append(i))
            )
        lanes.wait()
    assert seen == {k: list(range(k, 40, 4)) for k in range(4)}


def test_lanes_run_at_once_and_a_task_waits_for_the_tasks_it_follows():
    started = threading.Event()
    release = threading.Event()
    order = []
    with Lanes(2) as lanes:

        def slow():
            started.set()
            release.wait(5)
            order.append("slow")
            return 7

        first = lanes.submit("a", slow)
        assert started.wait(5)
        # another lane runs while lane a is busy
        lanes.submit("b", lambda: order.append("b")).result(timeout=5)
        assert order == ["b"]
        after = lanes.submit("b", lambda: order.append("after a"), after=[first])
        time.sleep(0.05)
        assert not after.done()  # waits for lane a's task, on no thread
        release.set()
        after.result(timeout=5)
        lanes.wait()
    assert order == ["b", "slow", "after a"] and first.result() == 7


@pytest.mark.parametrize("threads", [1, 2])
def test_the_first_error_stops_the_lanes_and_reaches_the_caller(threads):
    ran = []
    lanes = Lanes(threads, backlog=100)
    with pytest.raises(ZeroDivisionError):
        with lanes:
            lanes.submit("a", lambda: 1 / 0)
            for i in range(50):
                lanes.submit("b", lambda i=i: (time.sleep(0.001), ran.append(i)))
            lanes.wait()
    assert len(ran) < 50  # dropped once the error was seen
    with pytest.raises(ZeroDivisionError):
        lanes.submit("c", lambda: None)


def test_a_full_lane_holds_the_caller_back():
    gate = threading.Event()
    with Lanes(2, backlog=2) as lanes:
        lanes.submit("a", lambda: gate.wait(5))
        lanes.submit("a", lambda: None)
        lanes.submit("a", lambda: None)  # the first has started: two held
        waiter = threading.Thread(target=lambda: lanes.submit("a", lambda: None))
        waiter.start()
        waiter.join(0.1)
        assert waiter.is_alive()
        gate.set()
        waiter.join(5)
        assert not waiter.is_alive()
        lanes.wait()

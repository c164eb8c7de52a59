"""Faults injected where messages leave an agent: loss, duplicates, delay, reordering and
partitions on a timetable (``live.faults``), seeded per agent so that a fleet's faults repeat."""

from __future__ import annotations

import threading
from collections import Counter
from collections.abc import Callable

import numpy as np

from ..config import FaultConfig


class FaultyLinks:
    """``send(receiver, chunk)`` of agent ``name`` through the faults of ``faults`` to
    ``put(receiver, chunk)``; ``now()`` gives the mission time (seconds) the partitions'
    timetable is read in. :attr:`counts` says what was done."""

    def __init__(
        self,
        faults: FaultConfig,
        name: str,
        index: int,
        put: Callable[[str, bytes], None],
        now: Callable[[], float],
    ):
        self.faults, self.name, self._send, self._now = faults, name, put, now
        self.rng = np.random.default_rng([faults.seed, index])
        self.held: dict[str, bytes] = {}  # per receiver, a frame to send after the next one
        self.counts: Counter = Counter()
        self._timers: list[threading.Timer] = []

    def cut_off(self, receiver: str, t: float) -> bool:
        """Whether a partition separates this agent from ``receiver`` at time ``t``."""
        return any(
            p.start <= t < p.end and (self.name in p.agents) != (receiver in p.agents)
            for p in self.faults.partitions
        )

    def send(self, receiver: str, frame: bytes) -> None:
        """One chunk (or any frame) through the faults."""
        f = self.faults
        if self.cut_off(receiver, self._now()):
            self.counts["partitioned"] += 1
            return
        if self.rng.random() < f.loss:
            self.counts["lost"] += 1
            return
        if receiver not in self.held and self.rng.random() < f.reorder:
            self.held[receiver] = frame  # goes after the next frame to this receiver
            self.counts["reordered"] += 1
            return
        copies = 2 if self.rng.random() < f.duplicate else 1
        self.counts["duplicated"] += copies - 1
        for _ in range(copies):
            self._later(receiver, frame)
        if receiver in self.held:
            self._later(receiver, self.held.pop(receiver))

    def flush(self) -> None:
        """Send the frames held back for reordering, and wait for the delayed ones."""
        for receiver in list(self.held):
            self._send(receiver, self.held.pop(receiver))
        for t in self._timers:
            t.join()
        self._timers.clear()

    def _later(self, receiver: str, frame: bytes) -> None:
        delay = self.rng.uniform(0.0, self.faults.delay) if self.faults.delay > 0 else 0.0
        if delay <= 0:
            self._send(receiver, frame)
            return
        self.counts["delayed"] += 1
        timer = threading.Timer(delay, self._send, (receiver, frame))
        timer.daemon = True
        timer.start()
        self._timers = [t for t in self._timers if t.is_alive()] + [timer]

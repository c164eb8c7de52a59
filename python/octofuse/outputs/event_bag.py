"""A run replayable in time: after every group of exchanges, each exported agent's map of
every rule it fused a message into is streamed into a bag as ``octomap_msgs/msg/Octomap``
(and PointCloud2 of its occupied voxels) on ``/octofuse/RULE/AGENT/octomap`` (and
``.../occupied_cells``), stamped at bag start + exchange time.

Messages received at one instant are fused together, so an agent that received several at
the same time gets one message holding the map after all of them. Maps are written as they
are made (nothing is kept); the bag is put in place only complete (:class:`MapBagWriter`).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from pathlib import Path

from ..config import EXACT_MODES
from .rosbag_export import MapBagWriter, MapEvent

TOPIC = "/octofuse/{name}/octomap"
CLOUD_TOPIC = "/octofuse/{name}/occupied_cells"


class FusionEventBag:
    """The observer of :func:`octofuse.fusion.simulate.simulate` that writes the bag.

    ``select(agents)`` names the agents whose maps are written (default: all). Set
    ``start_ns`` (the bags' start) before the run. ``close()`` finishes the bag and puts it in
    place (``finish()`` and ``put_in_place()``, as :class:`MapBagWriter`), ``abort()`` drops it.
    """

    def __init__(
        self,
        path: str | os.PathLike,
        *,
        frame_id: str = "map",
        select: Callable[[list[str]], Sequence[str]] | None = None,
        every: int = 1,
        clouds_only: bool = False,
        say: Callable[[str], None] = lambda _m: None,
    ):
        self.writer = MapBagWriter(
            path, frame_id=frame_id, topic=None if clouds_only else TOPIC, cloud_topic=CLOUD_TOPIC
        )
        self.path = Path(path)
        self.start_ns = 0
        #: an agent's map written at every ``every``-th fusion it receives
        self.every = every
        #: map messages the run will write (set before the run), for the size projection
        self.expected = 0
        self._say = say
        self._select = select
        self._agents: set[str] | None = None
        self._seen: dict[str, int] = {}  # rule -> fusion records handled
        self._received: dict[tuple[str, str], int] = {}  # (rule, agent) -> fusions received
        self._projected = False

    @property
    def messages(self) -> int:
        """Map messages written so far."""
        return self.writer.count

    def __call__(self, t: float, group, net, scans) -> None:
        if self._agents is None:
            self._agents = set(self._select(list(net.agents)) if self._select else net.agents)
        stamp = self.start_ns + round(t * 1e9)
        for rule in net.rules:
            records = net.traffic[rule].fusions
            new = records[self._seen.get(rule, 0) :]
            self._seen[rule] = len(records)
            for agent in dict.fromkeys(e.receiver for e in new if e.receiver in self._agents):
                k = self._received[rule, agent] = self._received.get((rule, agent), 0) + 1
                if (k - 1) % self.every:
                    continue
                m = net.fused[rule][agent]
                if rule in EXACT_MODES:  # kept unclamped while fusing; written clamped
                    from ..fusion.channel_filter import clamped

                    m = clamped(m)
                self.writer.write(MapEvent(f"{rule}/{agent}", stamp, m))
        self._project()

    def _project(self) -> None:
        """Once a tenth of the expected messages are written: say the bag's expected size."""
        w = self.writer
        if self._projected or not self.expected or w.count * 10 < self.expected:
            return
        self._projected = True
        mb = w.bytes / w.count * self.expected / 1e6
        self._say(
            f"--export-bag: {w.count} of about {self.expected} map messages written, "
            f"about {mb:,.1f} MB expected (maps grow: likely more; --bag-every N and "
            "--bag-clouds-only write less)"
        )

    def close(self) -> Path:
        return self.writer.close()

    def finish(self) -> None:
        self.writer.finish()

    def put_in_place(self) -> Path:
        return self.writer.put_in_place()

    def abort(self) -> None:
        self.writer.abort()

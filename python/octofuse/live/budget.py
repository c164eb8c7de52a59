"""Each link's byte budget (``live.link_budget``): the bytes a link carries in any second, per
direction, counted over a sliding second of the agent's clock (mission time: real time at
speed 1). A message gets what the last second left; :class:`~octofuse.fusion.link.Link` fits a
delta into it by its most informative voxels and keeps the rest for later messages."""

from __future__ import annotations

from collections import defaultdict, deque

from ..fusion.wire import DEFAULT_MAX_PAYLOAD
from .chunks import HEAD_BYTES, wire_bytes

#: bytes an OctoMap stream's node takes (its log-odds and child mask)
NODE_BYTES = 5
#: the nodes of a map of one finest voxel (the root and one node per level below it)
MIN_NODES = 17


class LinkBudget:
    """``bytes_per_s`` on each link, counted per receiver."""

    def __init__(self, bytes_per_s: int, max_chunk_bytes: int):
        self.rate, self.chunk = bytes_per_s, max_chunk_bytes
        self._sent: dict[str, deque] = defaultdict(deque)  # receiver -> (time, bytes), 1 s
        #: per receiver, the most bytes sent in any second
        self.peak: dict[str, int] = defaultdict(int)

    def allowance(self, receiver: str, t: float) -> int:
        """Bytes a message to ``receiver`` at time ``t`` may take on the wire."""
        return self.rate - sum(n for _, n in self._window(receiver, t))

    def max_nodes(self, receiver: str, t: float, empty_frame: int) -> int:
        """Nodes of map a message to ``receiver`` at ``t`` may carry, its frame without nodes
        taking ``empty_frame`` bytes (a few more for the node count's digits)."""
        room = self.allowance(receiver, t)
        room -= HEAD_BYTES * -(-room // (self.chunk - HEAD_BYTES))  # chunk headers, at most
        return max(0, min(room - empty_frame - 20, DEFAULT_MAX_PAYLOAD) // NODE_BYTES)

    def spend(self, receiver: str, t: float, frame: bytes) -> int:
        """Count ``frame`` sent to ``receiver`` at ``t``; its bytes on the wire (with the
        headers of its chunks)."""
        n = wire_bytes(len(frame), self.chunk)
        window = self._window(receiver, t)
        window.append((t, n))
        self.peak[receiver] = max(self.peak[receiver], sum(b for _, b in window))
        return n

    def _window(self, receiver: str, t: float) -> deque:
        """What went to ``receiver`` in the second up to ``t``."""
        sent = self._sent[receiver]
        while sent and sent[0][0] <= t - 1.0:
            sent.popleft()
        return sent

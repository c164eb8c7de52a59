"""A run's fusion events up to an instant: what each link carried, what each agent lost."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field


@dataclass
class Until:
    """The first ``count`` fusion events of one rule, summed."""

    count: int
    time_s: float  #: the time of the last of them (0 before the first)
    #: (sender, receiver) -> messages fused and voxels fused over that link
    messages: dict[tuple[str, str], int] = field(default_factory=dict)
    voxels: dict[tuple[str, str], int] = field(default_factory=dict)
    #: agent -> information loss accumulated over the messages it fused (nats)
    loss: dict[str, float] = field(default_factory=dict)
    last: dict | None = None  #: the last event (as summary.json records it)

    def link_messages(self, a: str, b: str) -> int:
        """Messages fused over the link between ``a`` and ``b``, both ways."""
        return self.messages.get((a, b), 0) + self.messages.get((b, a), 0)

    def link_voxels(self, a: str, b: str) -> int:
        return self.voxels.get((a, b), 0) + self.voxels.get((b, a), 0)


def events_of(events: Sequence[dict], rule: str) -> list[dict]:
    """The events of ``rule`` in time order (summary.json's ``fusion_events`` rows)."""
    return sorted((e for e in events if e["rule"] == rule), key=lambda e: e["t"])


def until(events: Sequence[dict], count: int) -> Until:
    """The sums over the first ``count`` of ``events`` (one rule's, in time order)."""
    done = events[: max(0, count)]
    out = Until(len(done), done[-1]["t"] if done else 0.0, last=done[-1] if done else None)
    for e in done:
        link = (e["sender"], e["receiver"])
        out.messages[link] = out.messages.get(link, 0) + 1
        out.voxels[link] = out.voxels.get(link, 0) + (e.get("voxels") or 0)
        out.loss[e["receiver"]] = out.loss.get(e["receiver"], 0.0) + (e.get("loss") or 0.0)
    return out

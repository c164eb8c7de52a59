"""What the page reads: a source of maps, events and scores. :class:`.run_folder.RunFolder`
reads a finished run's folder; a live fleet can provide the same and call the page's
``refresh()`` when its maps change."""

from __future__ import annotations

from typing import Protocol

from .voxels import Voxels


class MapSource(Protocol):
    title: str  #: what the page's heading names
    agents: list[str]
    rules: list[str]
    links: list[tuple[str, str]]  #: the graph's links, as agent names
    events: list[dict]  #: fusion events: t, rule, sender, receiver, voxels, loss
    means: dict[str, dict]  #: rule -> mean scores (kl_mean, overconfidence, agreement, ...)
    loss_range: tuple[float, float] | None  #: one colour range of loss for every rule
    resolution: float  #: the finest voxel size, metres
    #: what a live source calls when its maps changed (the page sets it: its redraw)
    on_change: object

    def has_central(self) -> bool:
        """Whether there is a centralized map to show and compare with."""

    def agents_of(self, rule: str) -> list[str]:
        """The agents with a map of ``rule``."""

    def occupancy(self, rule: str, agent: str) -> Voxels:
        """The occupied voxels of a map (rule ``"centralized"``: the centralized map),
        valued by log-odds, in the common frame."""

    def loss(self, rule: str, agent: str) -> Voxels | None:
        """The occupied voxels of an agent's map valued by accumulated information loss
        (nats), None where there is none."""

    def difference(self, rule: str, agent: str) -> Voxels:
        """An agent's map against the centralized map (:mod:`.difference`)."""

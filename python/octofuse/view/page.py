"""The viewer's page (viser): a map of the run coloured by occupancy, information loss or
its difference to the centralized map, with rule and agent chosen in the side panel; the
fusion events up to a chosen instant (links and their traffic, loss per agent); the scores.

The page reads everything from a source (:class:`.source.MapSource`; a run's folder is
:class:`.run_folder.RunFolder`); :meth:`RunPage.refresh` redraws from it, so a live source
can feed it.
"""

from __future__ import annotations

import html
import threading

import numpy as np

from . import palette
from .difference import class_counts
from .events import events_of, until
from .run_folder import CENTRALIZED
from .source import MapSource
from .voxels import Detail, Voxels, by_size, within_budget

OCCUPANCY, LOSS, DIFFERENCE = "occupancy", "information loss", "difference to centralized"
#: voxels drawn at most by default (frame times by budget: benchmarks/README.md)
DEFAULT_BUDGET = 300_000
NODE_COLOR, LINK_COLOR, LAST_LINK_COLOR = (30, 30, 30), (90, 140, 200), (255, 140, 0)


class RunPage:
    """The page of ``source`` on ``server`` (a ``viser.ViserServer``)."""

    def __init__(self, source: MapSource, server, budget: int = DEFAULT_BUDGET):
        self.source, self.server = source, server
        self._lock = threading.Lock()  # one redraw at a time
        self._drawn: list = []  # the scene nodes of the map
        self.status = ""  # what the map shows, as the panel says it
        server.scene.set_up_direction("+z")
        gui = server.gui
        gui.add_markdown(f"**octofuse** · {html.escape(source.title)}")
        maps = ([CENTRALIZED] if source.has_central() else []) + list(source.rules)
        self.map = gui.add_dropdown("map", maps, initial_value=maps[min(1, len(maps) - 1)])
        self.agent = gui.add_dropdown("agent", self._agents(self.map.value) or ["–"])
        self.colour = gui.add_dropdown(
            "colour by", (OCCUPANCY, LOSS, DIFFERENCE), initial_value=LOSS
        )
        self.budget = gui.add_slider(
            "voxel budget",
            min=min(10_000, budget),
            max=max(2_000_000, budget),
            step=10_000,
            initial_value=budget,
        )
        self.legend = gui.add_html("")
        self.detail = gui.add_html("")
        with gui.add_folder("fusion events"):
            self.event = gui.add_slider("event", min=0, max=1, step=1, initial_value=1)
            self.event_text = gui.add_html("")
        with gui.add_folder("summary", expand_by_default=False):
            gui.add_html(summary_table(source.means))
        self.map.on_update(lambda _: self._map_chosen())
        for control in (self.agent, self.colour, self.budget):
            control.on_update(lambda _: self.draw_map())
        self.event.on_update(lambda _: self.draw_events())
        self.refresh()

    # -- choices ---------------------------------------------------------------------
    def _agents(self, rule: str) -> list[str]:
        return list(self.source.agents) if rule == CENTRALIZED else self.source.agents_of(rule)

    def _map_chosen(self) -> None:
        agents = self._agents(self.map.value) or ["–"]
        before = self.agent.value
        if tuple(self.agent.options) != tuple(agents):
            self.agent.options = agents  # a new value redraws through its callback
        if self.agent.value == before:
            self.draw_map()
        self._events_of_rule()

    def _events_of_rule(self) -> None:
        events = self._rule_events()
        before = self.event.value
        self.event.max = max(1, len(events))
        self.event.value = len(events)  # a new value redraws through its callback
        if self.event.value == before:
            self.draw_events()

    def _rule_events(self) -> list[dict]:
        rule = self.map.value if self.map.value != CENTRALIZED else (self.source.rules or [""])[0]
        return events_of(self.source.events, rule)

    def refresh(self) -> None:
        """Redraw everything from the source."""
        self.draw_map()
        self._events_of_rule()
        self._place_camera()

    # -- the map ---------------------------------------------------------------------
    def chosen_voxels(self) -> tuple[Voxels | None, str, str]:
        """The voxels of the current choice, their colouring and a note on what is shown."""
        rule, agent, colour = self.map.value, self.agent.value, self.colour.value
        src = self.source
        name = "centralized map" if rule == CENTRALIZED else f"{agent}, {rule}"
        if rule != CENTRALIZED and agent not in self._agents(rule):
            return None, OCCUPANCY, f"{rule}: no agent's map in the run's folder"
        if colour == LOSS and rule != CENTRALIZED:
            v = src.loss(rule, agent)
            if v is not None:
                return v, LOSS, f"{name}: accumulated information loss"
            note = f"{name}: no loss recorded ({rule} loses nothing or no heat map was written)"
        elif colour == DIFFERENCE and rule != CENTRALIZED and src.has_central():
            return src.difference(rule, agent), DIFFERENCE, f"{name} against the centralized map"
        elif colour == OCCUPANCY:
            note = name
        elif rule == CENTRALIZED:
            note = f"{name}: occupancy (it fuses nothing: no loss, nothing to compare)"
        else:
            note = f"{name}: occupancy (no centralized map to compare with)"
        return src.occupancy(rule, agent), OCCUPANCY, note

    def draw_map(self) -> None:
        with self._lock:
            v, colouring, note = self.chosen_voxels()
            for node in self._drawn:
                node.remove()
            self._drawn = []
            if v is None or len(v) == 0:
                self.legend.content, self.detail.content = "", html.escape(note)
                self.status = note
                return
            combine = np.minimum if colouring == DIFFERENCE else np.maximum  # worst class wins
            d = within_budget(v, int(self.budget.value), self.source.resolution, combine)
            colours = self._colours(d.voxels, colouring, v)
            with self.server.atomic():
                for i, (size, idx) in enumerate(by_size(d.voxels).items()):
                    self._drawn.append(
                        self.server.scene.add_point_cloud(
                            f"/map/level{i}",
                            d.voxels.centers[idx],
                            colours[idx],
                            point_size=size,
                            point_shape="square",
                            point_shading="flat",
                            precision="float32",
                        )
                    )
            self.status = note
            self.detail.content = detail_note(note, len(v), d)

    def _colours(self, v: Voxels, colouring: str, whole: Voxels) -> np.ndarray:
        if colouring == LOSS:
            lo, hi = self.source.loss_range or (0.0, float(np.max(whole.values)))
            self.legend.content = palette.loss_legend(lo, hi)
            return palette.loss_colors(v.values, lo, hi)
        if colouring == DIFFERENCE:
            self.legend.content = palette.difference_legend(class_counts(whole))
            return palette.difference_colors(v.values)
        self.legend.content = palette.occupancy_legend()
        return palette.occupancy_colors(v.values)

    def _place_camera(self) -> None:
        if not self.source.has_central():
            return
        lo, hi = self.source.occupancy(CENTRALIZED, "").bounds
        centre, extent = (lo + hi) / 2, float(np.max(hi - lo))
        cam = self.server.initial_camera
        cam.look_at = tuple(centre)
        cam.position = tuple(centre + np.array([-0.4, -0.75, 0.65]) * extent)

    # -- the events and the graph ----------------------------------------------------
    def draw_events(self) -> None:
        events = self._rule_events()
        now = until(events, int(self.event.value))
        self.event_text.content = events_note(
            now, len(events), self.source.agents, self.source.links
        )
        self._draw_graph(now)

    def _draw_graph(self, now) -> None:
        src = self.source
        if not src.has_central() or not src.agents:
            return
        lo, hi = src.occupancy(CENTRALIZED, "").bounds
        where = graph_layout(src.agents, lo, hi)
        scene = self.server.scene
        with self.server.atomic():
            scene.add_point_cloud(
                "/graph/agents",
                np.array([where[a] for a in src.agents]),
                NODE_COLOR,
                point_size=float(np.max(hi - lo)) / 100,
                point_shape="circle",
                precision="float32",
            )
            for a in src.agents:
                scene.add_label(
                    f"/graph/agent_{a}", a, position=tuple(where[a]), anchor="bottom-center"
                )
            if not src.links:
                return
            last = now.last and {now.last["sender"], now.last["receiver"]}
            points = np.array([[where[a], where[b]] for a, b in src.links])
            colours = np.array(
                [
                    [
                        LAST_LINK_COLOR
                        if last == {a, b}
                        else LINK_COLOR
                        if now.link_messages(a, b)
                        else (200, 200, 200)
                    ]
                    * 2
                    for a, b in src.links
                ],
                dtype=np.uint8,
            )
            scene.add_line_segments(
                "/graph/links", points, colours, thickness=3, thickness_units="screen"
            )
            for i, (a, b) in enumerate(src.links):
                scene.add_label(
                    f"/graph/link{i}",
                    f"{now.link_messages(a, b)} msg",
                    position=tuple((where[a] + where[b]) / 2),
                    anchor="center-center",
                    font_screen_scale=0.7,
                )


def graph_layout(agents, lo: np.ndarray, hi: np.ndarray) -> dict[str, np.ndarray]:
    """The agents on a circle above the map (positions in metres)."""
    centre, extent = (lo + hi) / 2, float(np.max(hi[:2] - lo[:2]))
    out = {}
    for i, a in enumerate(agents):
        angle = 2 * np.pi * i / len(agents)
        out[a] = np.array(
            [
                centre[0] + 0.45 * extent * np.cos(angle),
                centre[1] + 0.45 * extent * np.sin(angle),
                hi[2] + 0.25 * extent,
            ]
        )
    return out


def detail_note(note: str, total: int, d: Detail) -> str:
    """What the map shows and at which level of detail."""
    drawn = f"{len(d.voxels):,} voxels drawn"
    if d.merged:
        drawn += (
            f" of {total:,}: to fit the budget, merged into cells of up to {d.cell:g} m, "
            "finer near the middle of the map"
        )
    return f"<div style='font-size:0.8em'>{html.escape(note)}<br>{drawn}</div>"


def events_note(now, total: int, agents, links) -> str:
    """The instant, the last event, each link's traffic and each agent's loss so far."""
    out = [
        f"<div style='font-size:0.8em'><b>{now.count} of {total} fusions</b>, "
        f"t = {now.time_s:.2f} s"
    ]
    if now.last:
        e = now.last
        loss = "" if e.get("loss") is None else f", loss {e['loss']:.4g} nats"
        out.append(
            f"<br>last: {html.escape(e['sender'])} → {html.escape(e['receiver'])}, "
            f"{e.get('voxels') or 0:,} voxels{loss}"
        )
    rows = "".join(
        f"<tr><td>{html.escape(a)}–{html.escape(b)}</td>"
        f"<td align=right>{now.link_messages(a, b)}</td>"
        f"<td align=right>{now.link_voxels(a, b):,}</td></tr>"
        for a, b in links
    )
    out.append(
        "<table style='width:100%'><tr><th align=left>link</th><th>messages</th>"
        f"<th>voxels</th></tr>{rows}</table>"
    )
    rows = "".join(
        f"<tr><td>{html.escape(a)}</td><td align=right>{now.loss.get(a, 0.0):.4g}</td></tr>"
        for a in agents
    )
    out.append(
        "<table style='width:100%'><tr><th align=left>agent</th><th>loss so far "
        f"[nats]</th></tr>{rows}</table></div>"
    )
    return "".join(out)


def summary_table(means: dict[str, dict]) -> str:
    """The run's mean scores per rule (summary.json's ``mean``)."""
    cols = [
        ("kl_mean", "KL", "{:.4f}"),
        ("overconfidence", "over-conf.", "{:.1%}"),
        ("agreement", "agree", "{:.1%}"),
        ("loss_mean", "loss", "{:.3f}"),
    ]
    head = "".join(f"<th>{h}</th>" for _, h, _ in cols)
    rows = "".join(
        f"<tr><td>{html.escape(rule)}</td>"
        + "".join(
            f"<td align=right>{'–' if row.get(k) is None else f.format(row[k])}</td>"
            for k, _, f in cols
        )
        + "</tr>"
        for rule, row in means.items()
    )
    return (
        f"<table style='font-size:0.8em;width:100%'><tr><th align=left>rule</th>{head}"
        f"</tr>{rows}</table>"
    )

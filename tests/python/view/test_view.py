"""``octofuse view``: voxels within a budget, the difference to the centralized map, the events
up to an instant, a run's folder as the page's source, and the page's choices."""

from __future__ import annotations

import json
import socket
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bagfactory as bf  # noqa: E402
from bagfactory import run_cli  # noqa: E402
from octofuse.maps.infoloss import Leaves  # noqa: E402
from octofuse.view.difference import AGREEING, MISSED, OVER_CONFIDENT, difference_voxels  # noqa: E402
from octofuse.view.events import events_of, until  # noqa: E402
from octofuse.view.run_folder import CENTRALIZED, RunFolder  # noqa: E402
from octofuse.view.voxels import Voxels, merged_into_cells, within_budget  # noqa: E402

RES = 0.1
RULES = ["naive-bayes", "chernoff", "min-info-loss"]


def grid_voxels(keys, values, size=RES) -> Voxels:
    keys = np.asarray(keys, dtype=np.float64)
    return Voxels(
        (keys + 0.5) * size, np.full(len(keys), size), np.asarray(values, dtype=np.float32)
    )


# -- level of detail ------------------------------------------------------------------------


def test_merging_keeps_the_largest_value_of_each_cell():
    rng = np.random.default_rng(1)
    keys = np.unique(rng.integers(-30, 30, size=(2000, 3)), axis=0)
    v = grid_voxels(keys, rng.uniform(0, 5, len(keys)))
    merged = merged_into_cells(v, 4 * RES)
    want: dict = {}
    for k, value in zip(np.floor(keys / 4).astype(int).tolist(), v.values):
        want[tuple(k)] = max(want.get(tuple(k), -1.0), float(value))
    got = {
        tuple(np.floor(c / (4 * RES)).astype(int).tolist()): float(x)
        for c, x in zip(merged.centers, merged.values)
    }
    assert got == pytest.approx(want)
    assert np.all(merged.sizes == pytest.approx(4 * RES))


def test_larger_voxels_are_kept_as_they_are():
    small = grid_voxels([[0, 0, 0], [1, 0, 0]], [1.0, 2.0])
    big = Voxels(np.array([[3.2, 3.2, 3.2]]), np.array([1.6]), np.array([7.0], np.float32))
    both = Voxels(
        np.vstack([small.centers, big.centers]),
        np.append(small.sizes, big.sizes),
        np.append(small.values, big.values),
    )
    merged = merged_into_cells(both, 2 * RES)
    assert sorted(merged.values.tolist()) == [2.0, 7.0]
    assert sorted(merged.sizes.tolist()) == pytest.approx([2 * RES, 1.6])


@pytest.mark.parametrize("budget", [50, 400, 3000, 5000])
def test_a_budget_bounds_the_voxels_drawn_and_spends_it_near_the_focus(budget):
    keys = np.stack(np.meshgrid(*[np.arange(16)] * 3, indexing="ij"), -1).reshape(-1, 3)
    v = grid_voxels(keys, np.arange(len(keys)))  # 4096 voxels
    d = within_budget(v, budget, RES, focus=(0.0, 0.0, 0.0))  # a corner of the map
    assert d.merged == (budget < len(v))
    assert d.voxels.values.max() == v.values.max()  # the largest value is never averaged away
    assert np.sum(d.voxels.sizes**3) == pytest.approx(
        len(v) * RES**3
    )  # the voxels drawn fill the map's volume, no more, no less
    if not d.merged:
        assert len(d.voxels) == len(v)
        return
    assert budget - 8 < len(d.voxels) <= budget  # one more cell split would not fit
    away = np.linalg.norm(d.voxels.centers, axis=1)  # the map spans 0 .. 1.6 m
    assert d.voxels.sizes[away < 0.5].max() < d.voxels.sizes[away > 2.0].max()


def test_merged_cells_take_the_smallest_value_when_asked():
    v = grid_voxels([[0, 0, 0], [1, 1, 1], [2, 0, 0]], [2.0, 0.0, 1.0])
    m = merged_into_cells(v, 2 * RES, np.minimum)
    assert sorted(m.values.tolist()) == [0.0, 1.0]


# -- difference to the centralized map ------------------------------------------------------


def leaves(keys, values) -> Leaves:
    v = grid_voxels(keys, values)
    return Leaves(v.centers, v.sizes, v.values, np.full(len(v), 16, np.uint8))


def test_each_voxel_takes_its_class_against_the_centralized_map():
    central = leaves([[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]], [1.0, 1.0, -1.0, 2.0])
    agent = leaves([[0, 0, 0], [1, 0, 0], [2, 0, 0], [4, 0, 0]], [1.05, -0.5, 3.5, 0.4])
    d = difference_voxels(agent, central, RES, tol=0.1)
    got = {int(round(c[0] / RES - 0.5)): int(k) for c, k in zip(d.centers, d.values)}
    assert got == {
        0: AGREEING,  # both occupied, nearly as certain
        1: MISSED,  # the agent holds it free
        2: OVER_CONFIDENT,  # the agent holds it occupied, and more surely than free
        3: MISSED,  # the agent does not know it
        4: OVER_CONFIDENT,
    }  # only the agent knows it, and holds it occupied


# -- events ---------------------------------------------------------------------------------


def test_events_up_to_an_instant_sum_traffic_per_link_and_loss_per_agent():
    events = [
        {"t": 2.0, "rule": "r", "sender": "a", "receiver": "b", "voxels": 10, "loss": 1.5},
        {"t": 1.0, "rule": "r", "sender": "b", "receiver": "a", "voxels": 4, "loss": 0.5},
        {"t": 1.5, "rule": "s", "sender": "a", "receiver": "b", "voxels": 9, "loss": 9.0},
        {"t": 3.0, "rule": "r", "sender": "b", "receiver": "c", "voxels": 7, "loss": None},
    ]
    mine = events_of(events, "r")
    assert [e["t"] for e in mine] == [1.0, 2.0, 3.0]
    now = until(mine, 2)
    assert (now.count, now.time_s, now.last["receiver"]) == (2, 2.0, "b")
    assert now.link_messages("a", "b") == now.link_messages("b", "a") == 2
    assert now.link_voxels("a", "b") == 14 and now.link_messages("b", "c") == 0
    assert now.loss == {"a": 0.5, "b": 1.5}
    assert until(mine, 0).last is None and until(mine, 3).link_voxels("c", "b") == 7


# -- a run's folder -------------------------------------------------------------------------


@pytest.fixture(scope="module")
def run_folder(tmp_path_factory):
    robots = bf.team(3)
    bag = bf.robot_recording(robots, bf.team_times(robots, 4)).write(
        tmp_path_factory.mktemp("bag") / "team", "mcap"
    )
    out = tmp_path_factory.mktemp("run") / "out"
    from octofuse.cli import main

    code = main(
        [
            "run",
            str(bag),
            "--rules",
            ",".join(RULES),
            "--topology",
            "ring",
            "--schedule",
            "periodic:1",
            "--resolution",
            str(RES),
            "--samples",
            "0",
            "--out",
            str(out),
        ]
    )
    assert code == 0
    return out


def test_a_run_folder_holds_what_the_page_shows(run_folder):
    src = RunFolder(run_folder)
    summary = json.loads((run_folder / "summary.json").read_text())
    assert src.rules == RULES and src.agents == summary["agents"] and src.has_central()
    assert len(src.links) == 3 and set(sum(src.links, ())) == set(src.agents)
    assert src.events == summary["fusion_events"] and src.loss_range == tuple(
        summary["exports"]["range"]
    )
    assert src.resolution == RES
    for rule in RULES:
        assert src.agents_of(rule) == src.agents
    central = src.occupancy(CENTRALIZED, "")
    assert len(central) > 0 and (central.values > 0).all()
    loss = src.loss("chernoff", src.agents[0])
    assert loss is not None and len(loss) > 0 and (loss.values >= 0).all()
    assert (src.loss("naive-bayes", src.agents[0]).values == 0).all()  # naive Bayes loses nothing
    d = src.difference("naive-bayes", src.agents[0])
    assert set(np.unique(d.values).tolist()) <= {OVER_CONFIDENT, MISSED, AGREEING}
    assert (d.values == OVER_CONFIDENT).sum() > (
        src.difference("chernoff", src.agents[0]).values == OVER_CONFIDENT
    ).sum()


def test_a_folder_without_a_summary_is_refused(tmp_path, capsys):
    code, _, err = run_cli(capsys, "view", tmp_path)
    assert code == 1
    assert "is not the output folder of a run (no summary.json)" in err


# -- the page, without a browser ------------------------------------------------------------


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def page(run_folder):
    viser = pytest.importorskip("viser")
    from octofuse.view.page import RunPage

    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    yield RunPage(RunFolder(run_folder), server, budget=50_000)
    server.stop()


def test_the_page_shows_the_choice_of_map_agent_and_colouring(page):
    from octofuse.view.page import DIFFERENCE, LOSS, OCCUPANCY

    assert page.map.value == "naive-bayes" and page.colour.value == LOSS
    page.map.value = "chernoff"  # each choice redraws the map
    assert page.status.endswith("chernoff: accumulated information loss")
    assert "information loss" in page.legend.content
    page.agent.value = page.source.agents[1]
    assert page.status == f"{page.source.agents[1]}, chernoff: accumulated information loss"
    page.colour.value = DIFFERENCE
    assert "over-confident" in page.legend.content and "against the centralized map" in page.status
    page.colour.value = OCCUPANCY
    page.map.value = CENTRALIZED
    assert page.status == "centralized map" and "occupancy probability" in page.legend.content


def test_the_event_slider_sums_the_events_so_far(page):
    page.map.value = "chernoff"
    n = len(events_of(page.source.events, "chernoff"))
    assert page.event.value == n > 0
    assert f"{n} of {n} fusions" in page.event_text.content
    page.event.value = 1
    assert f"1 of {n} fusions" in page.event_text.content


# -- the page in a real browser -------------------------------------------------------------

CHROMIUM = Path("/usr/bin/chromium")
#: WebGL without a GPU: Chromium's software rasteriser
SOFTWARE_WEBGL = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader"]
#: the part of the 1100 x 700 page the map is drawn in: left of the side panel, under the
#: notice Chromium's software WebGL brings up
MAP_AREA = {"x": 120, "y": 170, "width": 560, "height": 480}


def picture(tab, path: Path) -> np.ndarray:
    """The map area as an (H, W, 3) array, also saved as ``path``."""
    import matplotlib.image

    tab.screenshot(path=str(path), clip=MAP_AREA)
    return (matplotlib.image.imread(path)[..., :3] * 255).round().astype(np.uint8)


def drawn(rgb: np.ndarray) -> float:
    """The share of the pixels that are not the page's white background."""
    return float(np.mean(np.any(rgb < 235, axis=-1)))


def when(condition, tries: int = 120):
    """Poll ``condition()`` until it holds (every half second); its last value."""
    import time

    value = condition()
    for _ in range(tries):
        if value:
            break
        time.sleep(0.5)
        value = condition()
    return value


@pytest.mark.slow
def test_the_page_draws_the_run_in_a_browser_and_follows_the_rule_chosen(page, tmp_path):
    sync_api = pytest.importorskip("playwright.sync_api", reason="needs Playwright for Python")
    if not CHROMIUM.exists():
        pytest.skip("needs Chromium (Debian: apt-get install chromium)")
    errors: list[str] = []
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(CHROMIUM), args=SOFTWARE_WEBGL)
        try:
            tab = browser.new_page(viewport={"width": 1100, "height": 700})
            tab.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
            tab.on("pageerror", lambda e: errors.append(str(e)))
            tab.goto(f"http://127.0.0.1:{page.server.get_port()}/")
            tab.get_by_label("map", exact=True).click()
            tab.get_by_role("option", name="chernoff", exact=True).click()
            tab.get_by_text("a, chernoff: accumulated information loss").wait_for()
            when(lambda: drawn(picture(tab, tmp_path / "chernoff.png")) > 0.05)
            first = picture(tab, tmp_path / "chernoff.png")

            tab.get_by_label("map", exact=True).click()
            tab.get_by_role("option", name="min-info-loss", exact=True).click()
            tab.get_by_text("a, min-info-loss: accumulated information loss").wait_for()
            when(lambda: np.any(picture(tab, tmp_path / "min-info-loss.png") != first))
            second = picture(tab, tmp_path / "min-info-loss.png")
        finally:
            browser.close()
    assert errors == []
    assert drawn(first) > 0.05 and len(np.unique(first.reshape(-1, 3), axis=0)) > 20
    changed = np.mean(np.any(np.abs(first.astype(int) - second) > 8, axis=-1))
    assert changed > 0.005, changed  # the same voxels, coloured by another rule's losses


@pytest.mark.slow
def test_the_command_prints_the_pages_address(run_folder):
    import os
    import subprocess

    pytest.importorskip("viser")
    port = free_port()
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    with subprocess.Popen(
        [sys.executable, "-m", "octofuse", "view", str(run_folder), "--port", str(port)],
        stdout=subprocess.PIPE,
        text=True,
        env=env,
    ) as proc:
        try:
            line = proc.stdout.readline()
        finally:
            proc.terminate()
    assert line.strip() == f"viewer: http://localhost:{port}/ (Ctrl-C to stop)"


def test_a_run_written_without_agent_maps_shows_the_centralized_map_only(tmp_path, run_folder):
    import shutil

    viser = pytest.importorskip("viser")
    from octofuse.view.page import DIFFERENCE, RunPage

    folder = tmp_path / "run"
    shutil.copytree(run_folder, folder)
    for rule in RULES:
        shutil.rmtree(folder / rule)  # as --export none leaves it, with the centralized map
    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    try:
        page = RunPage(RunFolder(folder), server, budget=50_000)
        page.colour.value = DIFFERENCE
        assert page.status == "naive-bayes: no agent's map in the run's folder"
        page.map.value = CENTRALIZED
        assert page.status.startswith("centralized map: occupancy")
    finally:
        server.stop()

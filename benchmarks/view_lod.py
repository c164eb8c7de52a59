"""``octofuse view`` on a map of 5 million leaves: the time to the first picture and the frame
time in headless Chromium (software WebGL), at several voxel budgets.

The map is generated in memory (a warehouse's floor, walls and shelves at 4 cm, every voxel
occupied, a random loss each) and served by the viewer's page through a source with the
interface of a run's folder. For each budget: the page's preparation (merging into coarser
cells, colours), the time from opening the page to the first picture with the map, and the
frame times while the view is dragged round (requestAnimationFrame intervals).

    .venv/bin/python benchmarks/view_lod.py [--leaves 5000000] [--budgets 100000,300000,1000000]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import socket
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_common import log, machine  # noqa: E402
from octofuse.view.difference import AGREEING  # noqa: E402
from octofuse.view.voxels import Voxels  # noqa: E402

RES = 0.04
CHROMIUM = "/usr/bin/chromium"
SOFTWARE_WEBGL = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader"]
#: JavaScript: the intervals of ``frames`` animation frames, in milliseconds
FRAME_INTERVALS = """frames => new Promise(done => {
  const t = []; const step = now => { t.push(now);
    if (t.length > frames) done(t.slice(1).map((x, i) => x - t[i])); else requestAnimationFrame(step); };
  requestAnimationFrame(step); })"""


def warehouse(leaves: int, seed: int = 0) -> Voxels:
    """About ``leaves`` occupied voxels: a floor, outer walls and rows of shelves."""
    rng = np.random.default_rng(seed)
    side = int(np.sqrt(leaves * 0.55))  # the floor takes a bit more than half
    x, y = np.meshgrid(np.arange(side), np.arange(side // 2), indexing="ij")
    floor = np.stack([x.ravel(), y.ravel(), np.zeros(x.size, int)], -1)
    height = 75  # 3 m
    parts = [floor]
    for wall in (0, side // 2 - 1):  # the long walls
        xs, zs = np.meshgrid(np.arange(side), np.arange(1, height), indexing="ij")
        parts.append(np.stack([xs.ravel(), np.full(xs.size, wall), zs.ravel()], -1))
    left = leaves - sum(len(p) for p in parts)
    rows = max(1, left // (side // 2 * (height - 1)))
    for i in range(rows):  # shelves: walls across the hall
        ys, zs = np.meshgrid(np.arange(side // 2), np.arange(1, height), indexing="ij")
        parts.append(
            np.stack([np.full(ys.size, (i + 1) * side // (rows + 1)), ys.ravel(), zs.ravel()], -1)
        )
    keys = np.concatenate(parts)[:leaves]
    return Voxels(
        (keys + 0.5) * RES,
        np.full(len(keys), RES),
        rng.gamma(2.0, 0.3, len(keys)).astype(np.float32),
    )


class GeneratedRun:
    """One agent's map and the centralized map, the same voxels: a
    :class:`~octofuse.view.source.MapSource` for the page."""

    def __init__(self, voxels: Voxels):
        self.voxels = voxels
        self.title, self.agents, self.rules = "generated warehouse", ["robot1"], ["chernoff"]
        self.links, self.events, self.means = [], [], {}
        self.loss_range, self.resolution = (0.0, float(np.percentile(voxels.values, 99))), RES

    def has_central(self) -> bool:
        return True

    def agents_of(self, rule):
        return self.agents

    def occupancy(self, rule, agent):
        return Voxels(
            self.voxels.centers, self.voxels.sizes, np.full(len(self.voxels), 2.0, np.float32)
        )

    def loss(self, rule, agent):
        return self.voxels

    def difference(self, rule, agent):  # the same map: every voxel agrees
        return Voxels(
            self.voxels.centers, self.voxels.sizes, np.full(len(self.voxels), AGREEING, np.float32)
        )


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_for_map(tab, timeout_s: float = 600.0) -> None:
    """Wait until the middle of the page shows something other than its background."""
    import matplotlib.image

    t0 = time.perf_counter()
    while time.perf_counter() - t0 < timeout_s:
        png = tab.screenshot(clip={"x": 150, "y": 200, "width": 400, "height": 300})
        rgb = matplotlib.image.imread(io.BytesIO(png), format="png")[..., :3]
        if np.mean(np.any(rgb < 0.9, axis=-1)) > 0.05:
            return
        time.sleep(0.05)
    raise TimeoutError(f"no map on the page after {timeout_s:g} s")


def measure(source, budget: int, frames: int) -> dict:
    import viser
    from playwright.sync_api import sync_playwright

    from octofuse.view.page import RunPage

    with contextlib.redirect_stdout(io.StringIO()):  # viser's banner
        server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    try:
        t0 = time.perf_counter()
        page = RunPage(source, server, budget=budget)
        prepared = time.perf_counter() - t0
        drawn = int(
            page.detail.content.split(" voxels drawn")[0].split("<br>")[-1].replace(",", "")
        )
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, args=SOFTWARE_WEBGL)
            tab = browser.new_page(viewport={"width": 1100, "height": 700})
            tab.set_default_timeout(600_000)  # a frame of millions of voxels takes seconds
            t1 = time.perf_counter()
            tab.goto(f"http://127.0.0.1:{server.get_port()}/")
            wait_for_map(tab)
            loaded = time.perf_counter() - t1
            tab.mouse.move(350, 350)
            tab.mouse.down()
            intervals = []
            for i in range(frames):  # drag round: every frame draws the map anew
                tab.mouse.move(350 + 4 * (i % 50), 350)
                intervals += tab.evaluate(FRAME_INTERVALS, 1)
            tab.mouse.up()
            browser.close()
    finally:
        with contextlib.redirect_stdout(io.StringIO()):
            server.stop()
    ms = np.array(intervals)
    return {
        "budget": budget,
        "voxels_drawn": drawn,
        "prepare_s": prepared,
        "page_to_picture_s": loaded,
        "frame_ms_median": float(np.median(ms)),
        "frame_ms_p90": float(np.percentile(ms, 90)),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--leaves", type=int, default=5_000_000)
    ap.add_argument("--budgets", default="100000,300000,1000000")
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--json", type=Path, help="also write the figures here")
    a = ap.parse_args()
    t0 = time.perf_counter()
    source = GeneratedRun(warehouse(a.leaves))
    log(f"generated {len(source.voxels):,} voxels in {time.perf_counter() - t0:.1f} s")
    rows = []
    for budget in (int(b) for b in a.budgets.split(",")):
        rows.append(measure(source, budget, a.frames))
        log(json.dumps(rows[-1]))
    print(f"{len(source.voxels):,} leaves; {machine()}; headless Chromium, software WebGL")
    print(
        "| budget | voxels drawn | prepare [s] | open to picture [s] | first picture [s] "
        "| frame median [ms] | frame p90 [ms] |"
    )
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['budget']:,} | {r['voxels_drawn']:,} | {r['prepare_s']:.1f} | "
            f"{r['page_to_picture_s']:.1f} | {r['prepare_s'] + r['page_to_picture_s']:.1f} | "
            f"{r['frame_ms_median']:.0f} | {r['frame_ms_p90']:.0f} |"
        )
    if a.json:
        a.json.write_text(json.dumps({"leaves": len(source.voxels), "rows": rows}, indent=1))


if __name__ == "__main__":
    main()

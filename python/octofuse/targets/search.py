"""The multi-robot static target search of paper 000, section IV-B, as a simulation.

A 15 x 8 m lab, a static target, robots driving pre-defined search paths at 1 Hz for 65 s with
forward binary detectors, a common Gaussian-mixture prior, local Gaussian-sum particle filter
updates, and belief sharing every 13 s. Settings:

``3-robots``  robot 1 stands still at the bottom left, robots 2 and 3 plough lanes; the messages
              follow the cycle 1 -> 2 -> 3 -> 1 at k = 26 and 39 and 1 -> 3 -> 2 -> 1 at the other
              exchanges (k = 13, 52, 65), each hop fusing the receiver's belief with the sender's
              current one, in order.
``8-robots``  the max-robust network (Harary graph H_{3,8}); at each exchange every robot sends
              its belief to its neighbours and fuses what it receives in neighbour order.

Detectors: :class:`~octofuse.targets.detector.CameraDetector` (42.5 degree cone, 1 m, detection
probability 0.9 inside with soft edges, no false alarms). Filters: Gaussian-sum particle filter,
1000 particles per mixand, at most 15 mixands. The target is drawn from the prior where no robot
ever looks, so, as in the paper, nobody finds it.

Schemes: ``no-sharing``, ``centralized`` (all detections in one filter) and each fusion rule. The
WEP weight omega is the weight on the receiver's own belief. Information gain is
``KL(p_i || p_0)`` (paper 000 eq. 6) and the distance to the centralized belief
``KL(p_central || p_i)``, both by integration on a grid over the lab plus a 1 m margin.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..beliefs.mixture import GaussianMixture
from ..beliefs.mixture_fusion import MIXTURE_RULES, check_rule, fuse_mixtures
from ..beliefs.mixture_grid import grid_kl
from ..rule_names import FusionRule
from .detector import CameraDetector
from .particle_filter import gaussian_sum_update

SETTINGS = ("3-robots", "8-robots")
#: the mixture rules compared by default (all but min-entropy)
DEFAULT_RULES = tuple(r for r in MIXTURE_RULES if r != FusionRule.MIN_ENTROPY)
BASELINES = ("no-sharing", "centralized")
LAB = (15.0, 8.0)
SPEED = 0.3  # m/s


def common_prior() -> GaussianMixture:
    """The common prior over the target's position: eight modes around the lab."""
    means = [
        [2.0, 6.5],
        [4.5, 2.0],
        [7.5, 4.0],
        [10.5, 6.5],
        [13.0, 2.0],
        [13.0, 6.0],
        [2.5, 3.0],
        [9.5, 1.5],
    ]
    stds = [
        (1.0, 0.8),
        (1.4, 0.9),
        (1.2, 1.2),
        (1.5, 0.8),
        (1.0, 1.1),
        (0.9, 0.9),
        (0.8, 1.2),
        (1.3, 0.7),
    ]
    rho = [0.3, -0.2, 0.0, 0.25, -0.3, 0.1, 0.0, 0.2]
    covs = [[[sx * sx, r * sx * sy], [r * sx * sy, sy * sy]] for (sx, sy), r in zip(stds, rho)]
    return GaussianMixture([0.14, 0.12, 0.16, 0.13, 0.12, 0.11, 0.12, 0.10], means, covs)


def _polyline_poses(waypoints, n_steps: int, speed: float = SPEED) -> np.ndarray:
    """Poses ``(n_steps + 1, 3)`` at 1 Hz along a polyline at constant speed (stops at its end)."""
    pts = np.asarray(waypoints, dtype=float)
    seg = np.diff(pts, axis=0)
    length = np.hypot(seg[:, 0], seg[:, 1])
    cum = np.concatenate([[0.0], np.cumsum(length)])
    poses = np.empty((n_steps + 1, 3))
    for k in range(n_steps + 1):
        s = min(k * speed, cum[-1])
        i = min(int(np.searchsorted(cum, s, side="right")) - 1, len(seg) - 1)
        t = (s - cum[i]) / length[i]
        poses[k, :2] = pts[i] + t * seg[i]
        poses[k, 2] = math.atan2(seg[i, 1], seg[i, 0])
    return poses


def robot_paths(setting: str, n_steps: int) -> np.ndarray:
    """Poses ``(robots, n_steps + 1, 3)``; robot 1 stands still at the bottom left, facing the wall."""
    still = np.tile([1.0, 1.0, math.radians(200.0)], (n_steps + 1, 1))
    if setting == "3-robots":
        lanes = [
            [(2.0, 3.0), (13.0, 3.0), (13.0, 4.5), (2.0, 4.5)],
            [(13.5, 7.0), (3.0, 7.0), (3.0, 5.7), (13.5, 5.7)],
        ]
    else:
        lanes = [
            [(1.5, 2.0), (14.0, 2.0), (14.0, 2.9), (1.5, 2.9)],
            [(14.0, 7.3), (1.0, 7.3), (1.0, 6.4), (14.0, 6.4)],
            [(7.0, 0.6), (14.3, 0.6), (14.3, 1.5), (7.0, 1.5)],
            [(1.0, 4.0), (8.0, 4.0), (8.0, 5.0), (1.0, 5.0)],
            [(14.3, 4.0), (8.5, 4.0), (8.5, 5.0), (14.3, 5.0)],
            [(0.6, 7.5), (0.6, 3.5), (1.5, 3.5), (1.5, 7.5)],
            [(5.5, 1.0), (5.5, 7.5), (11.5, 7.5), (11.5, 2.5)],
        ]
    return np.stack([still] + [_polyline_poses(w, n_steps) for w in lanes])


def pick_target(
    prior: GaussianMixture, poses: np.ndarray, detector: CameraDetector, rng: np.random.Generator
) -> np.ndarray:
    """A draw from the prior inside the lab that no robot's detector ever covers."""
    flat = poses.reshape(-1, 3)
    for _ in range(200):
        cand = prior.sample(64, rng)
        inside = (
            (cand[:, 0] > 0.3)
            & (cand[:, 0] < LAB[0] - 0.3)
            & (cand[:, 1] > 0.3)
            & (cand[:, 1] < LAB[1] - 0.3)
        )
        for x in cand[inside]:
            if max(float(detector.p_detection(p, x)) for p in flat) < 1e-6:
                return x
    raise RuntimeError("no target position stays unseen by every robot; shorten the paths")


def exchanges(setting: str, n_robots: int, k: int) -> list[list[tuple[int, int]]]:
    """Message rounds at exchange step ``k``: each round is ``(sender, receiver)`` pairs sent from
    one snapshot; rounds run one after the other."""
    if setting == "3-robots":
        cycle = (0, 1, 2, 0) if k in (26, 39) else (0, 2, 1, 0)
        return [[(cycle[h], cycle[h + 1])] for h in range(3)]
    from octofuse.fusion.graph import make_graph

    graph = make_graph("max-robust:3", n_robots)
    return [[(j, i) for i in range(n_robots) for j in graph.neighbors(i)]]


@dataclass
class TargetSearchResult:
    """What :func:`run_target_search` measured (arrays indexed by step 0..duration and robot)."""

    setting: str
    schemes: tuple[str, ...]
    seed: int
    target: np.ndarray
    poses: np.ndarray
    prior: GaussianMixture
    info_gain: dict[str, np.ndarray] = field(default_factory=dict)  #: KL(p_i || p_0), (T+1, R)
    kl_to_central: dict[str, np.ndarray] = field(default_factory=dict)  #: KL(p_central || p_i)
    target_logpdf: dict[str, np.ndarray] = field(default_factory=dict)  #: log p_i(target)
    final: dict[str, list[GaussianMixture]] = field(default_factory=dict)
    fusions: list[dict] = field(default_factory=list)  #: one record per fusion
    detections: int = 0
    params: dict = field(default_factory=dict)
    out_dir: Path | None = None


def simulate(
    setting: str = "3-robots",
    rules=DEFAULT_RULES,
    seed: int = 0,
    *,
    duration: int = 65,
    comm_period: int = 13,
    n_samples: int = 1000,
    particles: int = 1000,
    max_components: int = 15,
    method: str = "moment-match",
    pair_samples: int = 1000,
    grid_step: float = 0.1,
    progress=None,
) -> TargetSearchResult:
    """Run every scheme of the search and measure it (no files written)."""
    if setting not in SETTINGS:
        raise ValueError(
            f"unknown target search setting {setting!r}; choose one of {', '.join(SETTINGS)}"
        )
    rules = tuple(check_rule(r) for r in rules)
    detector, prior = CameraDetector(), common_prior()
    poses = robot_paths(setting, duration)
    n_robots = poses.shape[0]
    target = pick_target(prior, poses, detector, np.random.default_rng([seed, 1]))
    obs_rng = np.random.default_rng([seed, 2])
    observed = np.array(
        [
            [detector.observe(poses[i, k], target, obs_rng) for k in range(duration + 1)]
            for i in range(n_robots)
        ]
    )
    n = int(round((LAB[0] + 2.0) / grid_step)) + 1, int(round((LAB[1] + 2.0) / grid_step)) + 1
    xs, ys = np.linspace(-1.0, LAB[0] + 1.0, n[0]), np.linspace(-1.0, LAB[1] + 1.0, n[1])
    pts = np.column_stack([c.ravel() for c in np.meshgrid(xs, ys, indexing="xy")])
    log_p0 = prior.logpdf(pts)
    res = TargetSearchResult(
        setting,
        BASELINES[::-1] + rules,
        seed,
        target,
        poses,
        prior,
        detections=int(observed.sum()),
        params=dict(
            duration=duration,
            comm_period=comm_period,
            n_samples=n_samples,
            particles=particles,
            max_components=max_components,
            method=method,
            pair_samples=pair_samples,
            grid=(n[0], n[1]),
            grid_extent=[-1.0, LAB[0] + 1.0, -1.0, LAB[1] + 1.0],
            detector=vars(detector),
        ),
    )
    central_log = []

    def update(belief, robot, k, rng):
        lik = lambda x, p=poses[robot, k], y=observed[robot, k]: detector.likelihood(y, p, x)  # noqa: E731
        return gaussian_sum_update(belief, lik, rng, particles, max_components)

    def measure(scheme, beliefs, k):
        logs = [b.logpdf(pts) for b in beliefs]
        res.info_gain[scheme][k] = [grid_kl(lp, log_p0) for lp in logs]
        res.target_logpdf[scheme][k] = [b.logpdf(target) for b in beliefs]
        if scheme == "centralized":
            central_log.append(logs[0])
        res.kl_to_central[scheme][k] = [grid_kl(central_log[k], lp) for lp in logs]

    for scheme in res.schemes:
        if progress:
            progress(f"{setting}: {scheme}")
        for table in (res.info_gain, res.kl_to_central, res.target_logpdf):
            table[scheme] = np.zeros((duration + 1, n_robots))
        rng = np.random.default_rng([seed, 3])  # every scheme starts from the same random stream
        beliefs = [prior] * n_robots
        measure(scheme, beliefs, 0)
        for k in range(1, duration + 1):
            if scheme == "centralized":
                b = beliefs[0]
                for i in range(n_robots):
                    b = update(b, i, k, rng)
                beliefs = [b] * n_robots
            else:
                beliefs = [update(beliefs[i], i, k, rng) for i in range(n_robots)]
            if scheme not in BASELINES and k % comm_period == 0:
                for round_ in exchanges(setting, n_robots, k):
                    snapshot = list(beliefs)
                    for sender, receiver in round_:
                        out = fuse_mixtures(
                            beliefs[receiver],
                            snapshot[sender],
                            rule=scheme,
                            n_samples=n_samples,
                            method=method,
                            max_components=max_components,
                            prior=prior,
                            seed=rng,
                            pair_samples=pair_samples,
                        )
                        gains = [
                            grid_kl(m.logpdf(pts), log_p0) for m in (beliefs[receiver], out.mixture)
                        ]
                        res.fusions.append(
                            dict(
                                scheme=scheme,
                                k=k,
                                sender=sender + 1,
                                receiver=receiver + 1,
                                gain_before=gains[0],
                                gain_after=gains[1],
                                **out.summary(),
                            )
                        )
                        beliefs[receiver] = out.mixture
            measure(scheme, beliefs, k)
        res.final[scheme] = beliefs
    return res

"""Reference WEP fusion of two 2-D mixtures by integration on a regular grid.

Slow but deterministic: the same costs as the importance-sampling search, with grid nodes as
samples (``g`` = 1 / cell area). Used to check :func:`fuse_mixtures` and to benchmark it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import logsumexp, softmax

from .mixture import GaussianMixture
from .mixture_fusion import check_rule
from .mixture_omega import WepCosts, choose_omega


@dataclass(frozen=True)
class Grid2D:
    """A regular grid over ``[lo_x, hi_x] x [lo_y, hi_y]`` with ``n`` nodes per axis."""

    lo: tuple[float, float]
    hi: tuple[float, float]
    n: int

    @property
    def axes(self) -> tuple[np.ndarray, np.ndarray]:
        return (
            np.linspace(self.lo[0], self.hi[0], self.n),
            np.linspace(self.lo[1], self.hi[1], self.n),
        )

    @property
    def points(self) -> np.ndarray:
        xs, ys = self.axes
        gx, gy = np.meshgrid(xs, ys, indexing="xy")
        return np.column_stack([gx.ravel(), gy.ravel()])

    @property
    def cell_area(self) -> float:
        return ((self.hi[0] - self.lo[0]) / (self.n - 1)) * (
            (self.hi[1] - self.lo[1]) / (self.n - 1)
        )

    @staticmethod
    def covering(*mixtures: GaussianMixture, n: int = 300, sigmas: float = 6.0) -> Grid2D:
        """A square-celled box holding every component's mean +- ``sigmas`` standard deviations."""
        lo = np.min(
            [
                np.min(m.means - sigmas * np.sqrt(np.diagonal(m.covariances, axis1=1, axis2=2)), 0)
                for m in mixtures
            ],
            axis=0,
        )
        hi = np.max(
            [
                np.max(m.means + sigmas * np.sqrt(np.diagonal(m.covariances, axis1=1, axis2=2)), 0)
                for m in mixtures
            ],
            axis=0,
        )
        return Grid2D((float(lo[0]), float(lo[1])), (float(hi[0]), float(hi[1])), int(n))


def grid_kl(log_p: np.ndarray, log_q: np.ndarray) -> float:
    """``KL(p || q)`` from log densities on the same grid (each normalised on the grid)."""
    p = softmax(log_p)
    return float(p @ ((log_p - logsumexp(log_p)) - (log_q - logsumexp(log_q))))


@dataclass(frozen=True)
class GridFusion:
    omega: float
    log_density: np.ndarray  #: log of the fused density at the grid points (normalised on the grid)
    kl_to_a: float
    kl_to_b: float
    info_loss: float


def grid_fuse(
    a: GaussianMixture,
    b: GaussianMixture,
    rule: str,
    grid: Grid2D,
    prior: GaussianMixture | None = None,
    omega: float | None = None,
) -> GridFusion:
    """The rule's omega and the fused density, both by integration on ``grid``."""
    if a.dim != 2 or b.dim != 2:
        raise ValueError("grid fusion is for 2-D mixtures")
    rule = check_rule(rule)
    pts = grid.points
    log_cell = math.log(grid.cell_area)
    log_a, log_b = a.logpdf(pts), b.logpdf(pts)
    log_nb = log_a + log_b
    if rule == "naive-bayes" and omega is None:
        log_f = log_nb - logsumexp(log_nb) - log_cell
        return GridFusion(math.nan, log_f, grid_kl(log_f, log_a), grid_kl(log_f, log_b), 0.0)
    costs = WepCosts(log_a, log_b, np.full(log_a.shape, -log_cell))
    nb = softmax(log_nb)
    info_a = info_b = None
    if prior is not None:
        log_p0 = prior.logpdf(pts)
        info_a, info_b = grid_kl(log_a, log_p0), grid_kl(log_b, log_p0)
    w = (
        omega
        if omega is not None
        else choose_omega(costs, rule, float(nb @ (log_a - log_b)), info_a, info_b)
    )
    log_w = w * log_a + (1.0 - w) * log_b
    log_f = log_w - logsumexp(log_w) - log_cell
    return GridFusion(
        float(w), log_f, grid_kl(log_f, log_a), grid_kl(log_f, log_b), grid_kl(log_nb, log_w)
    )

"""The interface every belief family shares with the occupancy rules."""

from __future__ import annotations

from typing import Protocol, TypeVar, runtime_checkable

import numpy as np

B = TypeVar("B", bound="Belief")


@runtime_checkable
class Belief(Protocol):
    """A normalisable density over R^d that robots can share and fuse.

    ``wep(other, w)`` is the weighted exponential product ``p^w q^(1-w)`` (normalised),
    ``multiply`` the naive-Bayes product ``p q``, and ``moments`` the mean and covariance.
    """

    @property
    def dim(self) -> int: ...

    def wep(self: B, other: B, w: float) -> B: ...

    def multiply(self: B, other: B) -> B: ...

    def moments(self) -> tuple[np.ndarray, np.ndarray]: ...

    def pdf(self, x: np.ndarray) -> np.ndarray: ...


def check_weight(w: float) -> float:
    """Return ``w`` as a float in [0, 1]; ``ValueError`` naming the value otherwise."""
    w = float(w)
    if not (0.0 <= w <= 1.0):  # also rejects NaN
        raise ValueError(f"WEP weight w = {w} is not in [0, 1]")
    return w

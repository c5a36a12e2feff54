"""Curves on the grid: an evaluation at env step ``x`` counts at the nearest grid point at or
after it; statistics over seeds (the rules are in docs/reports.md, "Binning")."""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from experiments.report.runs import Curve


def bin_of(x: float, spacing: float) -> float:
    """The grid point whose bin holds an evaluation at env step ``x``: the nearest grid point
    at or after it, ``spacing * ceil(x / spacing)`` (0 -> 0, 1..spacing -> spacing, ...)."""
    return spacing * math.ceil(round(x / spacing, 9))


def binned(curve: Curve, spacing: float) -> dict[float, float]:
    """One seed on the grid: grid point -> the latest evaluation in its bin."""
    values: dict[float, tuple[float, float]] = {}
    for x, y in zip(curve.xs, curve.ys, strict=True):
        point = bin_of(float(x), spacing)
        if point not in values or x >= values[point][0]:
            values[point] = (float(x), float(y))
    return {point: y for point, (_, y) in sorted(values.items())}


def seed_stats(seeds: Iterable[dict[float, float]]) -> tuple[np.ndarray, ...]:
    """Per grid point over the seeds present there: (x, mean, std, number of seeds)."""
    seeds = list(seeds)
    points = sorted({p for seed in seeds for p in seed})
    columns = [[seed[p] for seed in seeds if p in seed] for p in points]
    return (np.array(points, dtype=float), np.array([np.mean(c) for c in columns]),
            np.array([np.std(c) for c in columns]), np.array([len(c) for c in columns]))


def value_near(curve: Curve, at: float, spacing: float) -> float | None:
    """The evaluation nearest to env step ``at`` and at most ``spacing`` away (ties: the
    earlier), or None."""
    if not len(curve.xs):
        return None
    distance = np.abs(curve.xs - at)
    index = int(np.argmin(distance))  # argmin takes the first, i.e. the earlier, of a tie
    return float(curve.ys[index]) if distance[index] <= spacing else None


@dataclass
class Stat:
    """Mean and std over seeds, and how many seeds."""

    mean: float = math.nan
    std: float = math.nan
    n: int = 0

    @classmethod
    def of(cls, values: Iterable[float | None]) -> Stat:
        values = [v for v in values if v is not None and math.isfinite(v)]
        if not values:
            return cls()
        return cls(float(np.mean(values)), float(np.std(values)), len(values))

    def text(self, digits: int = 2) -> str:
        if not self.n:
            return "missing"
        return f"{self.mean:.{digits}f} ± {self.std:.{digits}f} (n={self.n})"

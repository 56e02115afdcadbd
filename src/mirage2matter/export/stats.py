"""Feature statistics for ``meta/stats.json`` (LeRobot: min, max, mean, std, count per feature).

Vectors get per-entry stats over frames; images get per-channel stats over frames and pixels, in
[0, 1], shaped [3, 1, 1]. Per-episode stats combine exactly (pooled mean and variance), so the
dataset's stats equal stats computed over all its frames at once.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

STAT_KEYS = ("min", "max", "mean", "std", "count")


def vector_stats(x: np.ndarray) -> dict[str, np.ndarray]:
    """Stats of x [T] or [T, D] over frames (float64); count = T."""
    x = np.asarray(x, dtype=np.float64)
    if x.ndim == 1:
        x = x[:, None]
    return {
        "min": x.min(axis=0),
        "max": x.max(axis=0),
        "mean": x.mean(axis=0),
        "std": x.std(axis=0),
        "count": np.array([x.shape[0]], dtype=np.int64),
    }


class ImageStatsAccumulator:
    """Per-channel stats of uint8 frames [H, W, 3] added one at a time (exact sums in int64/float64)."""

    def __init__(self) -> None:
        self.count = 0
        self._n_px = 0
        self._sum = np.zeros(3, np.float64)
        self._sumsq = np.zeros(3, np.float64)
        self._min = np.full(3, 255, np.int64)
        self._max = np.zeros(3, np.int64)

    def add(self, frame: np.ndarray) -> None:
        px = frame.reshape(-1, 3)
        # Sums of integers are exact in int64 (224^2 * 255^2 per frame is far below 2^63).
        self._sum += px.sum(axis=0, dtype=np.int64)
        sq = px.astype(np.int64)
        self._sumsq += (sq * sq).sum(axis=0)
        self._min = np.minimum(self._min, px.min(axis=0))
        self._max = np.maximum(self._max, px.max(axis=0))
        self._n_px += px.shape[0]
        self.count += 1

    def result(self) -> dict[str, np.ndarray]:
        if self.count == 0:
            raise ValueError("no frames to compute image stats from")
        mean = self._sum / self._n_px
        var = np.maximum(self._sumsq / self._n_px - mean * mean, 0.0)
        as_chw = lambda v: (np.asarray(v, np.float64) / 255.0).reshape(3, 1, 1)
        return {
            "min": as_chw(self._min),
            "max": as_chw(self._max),
            "mean": as_chw(mean),
            "std": as_chw(np.sqrt(var)),
            "count": np.array([self.count], dtype=np.int64),
        }


def aggregate(stats: Sequence[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """Combine per-episode stats of one feature (pooled mean / variance, weights = counts)."""
    if not stats:
        raise ValueError("no stats to aggregate")
    counts = np.array([float(s["count"][0]) for s in stats])
    means = np.stack([np.asarray(s["mean"], np.float64) for s in stats])
    var = np.stack([np.asarray(s["std"], np.float64) ** 2 for s in stats])
    w = counts.reshape((-1,) + (1,) * (means.ndim - 1))
    total = counts.sum()
    mean = (means * w).sum(axis=0) / total
    pooled = ((var + (means - mean) ** 2) * w).sum(axis=0) / total
    return {
        "min": np.min(np.stack([np.asarray(s["min"], np.float64) for s in stats]), axis=0),
        "max": np.max(np.stack([np.asarray(s["max"], np.float64) for s in stats]), axis=0),
        "mean": mean,
        "std": np.sqrt(np.maximum(pooled, 0.0)),
        "count": np.array([int(total)], dtype=np.int64),
    }


def to_json(stats: dict[str, np.ndarray]) -> dict[str, list]:
    return {k: np.asarray(stats[k]).tolist() for k in STAT_KEYS}


def from_json(d: dict[str, list]) -> dict[str, np.ndarray]:
    return {k: np.asarray(d[k], dtype=np.int64 if k == "count" else np.float64) for k in STAT_KEYS}

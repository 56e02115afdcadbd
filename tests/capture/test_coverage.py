"""Capture advice: what the views miss, from cameras and points alone."""

from __future__ import annotations

import numpy as np

from mirage2matter.capture.coverage import scene_coverage
from mirage2matter.geometry.camera import look_at


def _ring(azimuths_deg, radius=1.0, height=0.6):
    K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])
    return [look_at(np.array([radius * np.cos(np.radians(a)), radius * np.sin(np.radians(a)), height]),
                    np.zeros(3), np.array([0, 0, 1.0]), K, 640, 480, f"{i:03d}")
            for i, a in enumerate(azimuths_deg)]  # fmt: skip


def _table(n=3000, seed=0):
    rng = np.random.default_rng(seed)
    return np.c_[rng.uniform(-0.4, 0.4, (n, 2)), rng.uniform(0.0, 0.1, n)]


def test_an_orbit_covers_the_table():
    cov = scene_coverage(_ring(np.arange(0, 360, 12)), _table())
    assert cov.well_seen > 0.95 and not cov.azimuth_gaps_deg and not cov.advice
    assert "no gaps found" in cov.line


def test_half_an_orbit_and_few_views_get_advice():
    cov = scene_coverage(_ring(np.arange(0, 180, 15)), _table())
    assert len(cov.azimuth_gaps_deg) == 1
    start, end = cov.azimuth_gaps_deg[0]
    assert (end - start) % 360 > 150  # the unfilmed side
    assert any("only 12 views" in a for a in cov.advice) and any("walk around" in a for a in cov.advice)
    # three views in a narrow arc: most of the table is seen from one direction only
    cov = scene_coverage(_ring([0, 3, 6]), _table())
    assert cov.well_seen < 0.1 and cov.weak_regions and any("more angles" in a for a in cov.advice)

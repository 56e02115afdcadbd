"""How well the views cover the scene, and what to film more.

A Gaussian scene is only as good as the views of each surface: a surface seen from one side, or by one or two
keyframes, comes out as floaters and holes (on a real 10-photo tabletop: 15.1 dB held-out, a black hole where views
were sparse). From the registered cameras and the SfM points this says, in words a user can act on:

- how many keyframes registered (fewer than ``MIN_VIEWS`` is too few for a room-scale scene);
- which directions around the scene no camera looked from (a gap in the cameras' azimuths about the scene centre);
- which parts of the scene are seen by fewer than ``WELL_SEEN_VIEWS`` views, or only from a narrow range of
  directions (less than ``MIN_PARALLAX_DEG`` between the rays), grouped into regions with their centres.

Visibility is geometric (the point projects into the image, in front of the camera, within ``MAX_RANGE`` scene
extents); occlusion is ignored, so the figures are optimistic upper bounds.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..geometry.camera import Camera

__all__ = ["Coverage", "scene_coverage"]

MIN_VIEWS = 20
WELL_SEEN_VIEWS = 3
MIN_PARALLAX_DEG = 10.0
AZIMUTH_GAP_DEG = 90.0
MAX_RANGE = 3.0


@dataclass
class Coverage:
    """views: registered cameras; points: SfM points considered; well_seen: fraction of them seen by
    >= WELL_SEEN_VIEWS views with >= MIN_PARALLAX_DEG between rays; views_per_point_median; azimuth_gaps_deg:
    [(start, end)] ranges of directions about the scene centre (degrees, in the frame's x-y plane after the up
    axis) no camera looked from; weak_regions: [{"centre": [x, y, z], "points", "views_median"}] largest first;
    advice: what to film more, one line each."""

    views: int
    points: int
    well_seen: float
    views_per_point_median: float
    azimuth_gaps_deg: list[tuple[float, float]] = field(default_factory=list)
    weak_regions: list[dict] = field(default_factory=list)
    advice: list[str] = field(default_factory=list)

    def to_json(self) -> dict:
        return {"views": self.views, "points": self.points, "well_seen": self.well_seen,
                "views_per_point_median": self.views_per_point_median,
                "azimuth_gaps_deg": [list(g) for g in self.azimuth_gaps_deg], "weak_regions": self.weak_regions,
                "advice": self.advice}  # fmt: skip

    @property
    def line(self) -> str:
        head = (f"coverage: {self.views} views, {100 * self.well_seen:.0f} % of {self.points} points seen well "
                f"(>= {WELL_SEEN_VIEWS} views, >= {MIN_PARALLAX_DEG:g} deg apart)")  # fmt: skip
        return head + ("; " + "; ".join(self.advice) if self.advice else "; no gaps found")


def _up_axis(cameras: list[Camera]) -> np.ndarray:
    """The scene's up: opposite to the mean of the cameras' image-down axes (people hold cameras upright)."""
    down = np.mean([c.T_world_cam[:3, 1] for c in cameras], axis=0)
    n = np.linalg.norm(down)
    return -down / n if n > 1e-6 else np.array([0.0, 0.0, 1.0])


def _visibility(cameras: list[Camera], points: np.ndarray, max_depth: float) -> np.ndarray:
    """[V, N] bool: point n projects inside camera v's image, in front of it, closer than ``max_depth``."""
    vis = np.zeros((len(cameras), len(points)), dtype=bool)
    for v, cam in enumerate(cameras):
        uv, z = cam.project(points)
        with np.errstate(invalid="ignore"):
            vis[v] = (z > 1e-6) & (z < max_depth) & (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (
                uv[:, 1] < cam.height)  # fmt: skip
    return vis


def _max_parallax_deg(centres: np.ndarray, points: np.ndarray, vis: np.ndarray) -> np.ndarray:
    """[N] the largest angle between two rays that see each point (0 for points seen once or never)."""
    out = np.zeros(len(points))
    for n in range(len(points)):
        c = centres[vis[:, n]]
        if len(c) < 2:
            continue
        d = c - points[n]
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        # the widest pair is near the pair farthest from the mean direction: cheap and exact enough for advice
        m = d.mean(axis=0)
        m /= max(np.linalg.norm(m), 1e-12)
        a = d[np.argmin(d @ m)]
        out[n] = float(np.degrees(np.arccos(np.clip(np.min(d @ a), -1.0, 1.0))))
    return out


def _azimuth_gaps(centres: np.ndarray, centre: np.ndarray, up: np.ndarray, min_gap: float) -> list[tuple]:
    """Ranges of azimuth (degrees, in [0, 360)) about ``centre`` with no camera, wider than ``min_gap``."""
    x = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(up, x)
    d = centres - centre
    az = np.sort(np.degrees(np.arctan2(d @ y, d @ x)) % 360.0)
    if len(az) == 0:
        return [(0.0, 360.0)]
    gaps = np.diff(np.r_[az, az[0] + 360.0])
    return [(float(az[i]), float((az[i] + g) % 360.0)) for i, g in enumerate(gaps) if g > min_gap]


def _weak_regions(points: np.ndarray, weak: np.ndarray, n_views: np.ndarray, cell: float, top: int = 3) -> list:
    """Weakly seen points grouped on a voxel grid of side ``cell``: the largest groups, with centre and size."""
    if not weak.any():
        return []
    keys = np.floor(points[weak] / cell).astype(np.int64)
    uniq, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    out = []
    for k in np.argsort(-counts)[:top]:
        sel = inverse.ravel() == k
        out.append({"centre": np.round(points[weak][sel].mean(axis=0), 3).tolist(), "points": int(counts[k]),
                    "views_median": float(np.median(n_views[weak][sel]))})  # fmt: skip
    return out


def scene_coverage(cameras: list[Camera], points: np.ndarray, max_points: int = 20000, seed: int = 0) -> Coverage:
    """Coverage of ``points`` [N,3] (SfM points, any frame) by ``cameras``; see the module docstring."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(points) > max_points:  # a random subset: the figures are fractions
        points = points[np.random.default_rng(seed).choice(len(points), max_points, replace=False)]
    advice = []
    if not cameras or not len(points):
        lost = "no registered views or no points: film the scene again, slowly, from all around"
        return Coverage(len(cameras), len(points), 0.0, 0.0, [], [], [lost])
    centres = np.array([c.center for c in cameras])
    lo, hi = np.percentile(points, [5, 95], axis=0)
    extent = float(np.linalg.norm(hi - lo))
    vis = _visibility(cameras, points, MAX_RANGE * max(extent, 1e-6) + np.linalg.norm(centres - points.mean(0),
                                                                                         axis=1).max())  # fmt: skip
    n_views = vis.sum(axis=0)
    parallax = _max_parallax_deg(centres, points, vis)
    good = (n_views >= WELL_SEEN_VIEWS) & (parallax >= MIN_PARALLAX_DEG)
    up = _up_axis(cameras)
    centre = np.median(points, axis=0)
    gaps = _azimuth_gaps(centres, centre, up, AZIMUTH_GAP_DEG)
    regions = _weak_regions(points, ~good, n_views, cell=max(extent / 6, 1e-3))
    if len(cameras) < MIN_VIEWS:
        advice.append(f"only {len(cameras)} views registered: film at least {MIN_VIEWS} (a slow orbit of the table "
                      "at two heights)")  # fmt: skip
    for a, b in gaps:
        advice.append(f"no views over {(b - a) % 360 or 360:.0f} deg of the way around the scene (azimuth {a:.0f} to "
                      f"{b:.0f} deg): walk around that side too")  # fmt: skip
    well = float(good.mean())
    if well < 0.8:
        for r in regions:
            advice.append(f"{r['points']} points near {tuple(r['centre'])} are seen by {r['views_median']:g} views "
                          "(median) or from one direction: film that part from more angles")  # fmt: skip
    return Coverage(len(cameras), len(points), well, float(np.median(n_views)), gaps, regions, advice)

"""Objects in the metric point cloud: the support plane, and what stands on it, clustered and named.

The base-aligned SfM cloud (``calib/points_base.npy``) holds the table top as its largest
near-horizontal plane. Points a few millimetres to a few decimetres above it, and over it, are
clustered by distance (single linkage, like DBSCAN with min_samples 1 plus a minimum size); flat
clusters (a sheet of paper, the calibration board) are dropped. What is left are the objects.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .errors import ObjectsError

__all__ = [
    "MIN_CLUSTER_POINTS",
    "ObjectCluster",
    "Plane",
    "cluster_of",
    "find_objects",
    "fit_support_plane",
    "name_clusters",
]

# The calibration board lies on the table, so its plane is the table's (fit_support_plane's ``board``). On a real
# capture with a plain wooden table SfM put its points on the objects, not the table: the largest plane was the tops
# of two tins and a bottle, 4.5 cm over the board, with 4 points off the board within 1 cm of the board's plane
# (jimazeyu/colmap_handeye). Candidate planes lie within these of the board's (at its centre).
BOARD_NEAR_M = 0.01
BOARD_NEAR_DEG = 2.0
# With fewer table points than this the table's extent is unknown: objects are kept within NO_TABLE_REACH_M of the
# base (the robot's reach, and more) instead of over the table's points.
MIN_TABLE_POINTS = 30
NO_TABLE_REACH_M = 1.2


@dataclass
class Plane:
    """Points x with ``normal . x + offset = 0``; ``normal`` [3] unit, pointing up (to the cameras)."""

    normal: np.ndarray
    offset: float
    inliers: np.ndarray  # [M] bool over the points it was fitted to

    def height(self, points: np.ndarray) -> np.ndarray:
        """Signed distance [N] of points [N,3] above the plane."""
        return np.asarray(points, np.float64) @ self.normal + self.offset


@dataclass
class ObjectCluster:
    """One object's points [K,3] (base frame) and where it stands."""

    name: str
    points: np.ndarray
    centroid: np.ndarray  # [3]
    height: float  # top above the support plane, metres

    @property
    def footprint_centre(self) -> np.ndarray:
        return self.centroid[:2]


def cluster_of(points: np.ndarray, plane: Plane, name: str = "") -> ObjectCluster:
    """The cluster of ``points`` [K,3] (base frame) standing on ``plane``."""
    return ObjectCluster(name, points, points.mean(0), float(plane.height(points).max()))


def _ransac_plane(pts: np.ndarray, threshold: float, max_tilt_deg: float, iterations: int, seed: int,
                  board: tuple[np.ndarray, np.ndarray] | None) -> tuple[np.ndarray, np.ndarray] | None:  # fmt: skip
    """(normal [3], a point [3]) of the plane with the most points within ``threshold`` among RANSAC's candidates
    tilted at most ``max_tilt_deg`` from +z (and with ``board``, within BOARD_NEAR_M / BOARD_NEAR_DEG of it); None
    when none holds 3 points (with ``board``: MIN_TABLE_POINTS)."""
    rng = np.random.default_rng(seed)
    cos_tilt = np.cos(np.radians(max_tilt_deg))
    cos_board = np.cos(np.radians(BOARD_NEAR_DEG))
    best, best_count = None, -1
    for _ in range(iterations):
        a, b, c = pts[rng.choice(len(pts), 3, replace=False)]
        n = np.cross(b - a, c - a)
        norm = np.linalg.norm(n)
        if norm < 1e-12:
            continue
        n /= norm
        if abs(n[2]) < cos_tilt:
            continue
        if board is not None and (abs(n @ board[1]) < cos_board or abs((board[0] - a) @ n) > BOARD_NEAR_M):
            continue
        count = int((np.abs((pts - a) @ n) < threshold).sum())
        if count > best_count:
            best, best_count = (n, a), count
    return best if best_count >= (3 if board is None else MIN_TABLE_POINTS) else None


def fit_support_plane(
    points: np.ndarray,
    threshold: float = 0.003,
    max_tilt_deg: float = 30.0,
    iterations: int = 2000,
    seed: int = 0,
    board: tuple[np.ndarray, np.ndarray] | None = None,
) -> Plane:
    """RANSAC plane with the most points within ``threshold`` whose normal is within
    ``max_tilt_deg`` of +z (the base frame's up), refined by least squares on its inliers.

    ``board``: (centre [3], up normal [3]) of the calibration board, which lies on the table: only candidates within
    :data:`BOARD_NEAR_M` of its centre and :data:`BOARD_NEAR_DEG` of its normal count, and where none holds
    :data:`MIN_TABLE_POINTS` points (a table SfM found no texture on) the board's own plane is the table's."""
    pts = np.asarray(points, np.float64)
    if len(pts) < 3:
        raise ObjectsError(f"only {len(pts)} points; the support plane needs a point cloud (run align-scene first)")
    best = _ransac_plane(pts, threshold, max_tilt_deg, iterations, seed, board)
    if board is not None and best is None:  # a table SfM found no texture on: the board's plane is the table's
        n = np.asarray(board[1], np.float64) / np.linalg.norm(board[1])
        offset = -float(n @ np.asarray(board[0], np.float64))
        return Plane(n, offset, np.abs(pts @ n + offset) < threshold)
    if best is None:
        raise ObjectsError("no near-horizontal support plane found in the point cloud; is it aligned to the base?")
    n, a = best
    inliers = np.abs((pts - a) @ n) < threshold
    centre = pts[inliers].mean(0)
    _, _, vt = np.linalg.svd(pts[inliers] - centre, full_matrices=False)
    n = vt[2] if vt[2][2] > 0 else -vt[2]
    offset = -float(n @ centre)
    inliers = np.abs(pts @ n + offset) < threshold
    return Plane(n, offset, inliers)


# The fewest SfM points an object's cluster holds (find_objects' default; a box prompt splits a cluster into parts of
# at least this many).
MIN_CLUSTER_POINTS = 12

# A link longer than LINK_FLOOR_M must also be short for the denser of its two points: at most LINK_SPACING x that
# point's distance to its LINK_NEIGHBOURS-th nearest neighbour. A sparse object (the samples' banana: ~35 points
# along 18 cm, gaps up to 3.5 cm) keeps its long links; a few stray points between two textured objects (the public
# real capture: a tin, a bottle and a toy 2-3 cm apart, SfM's points ~5 mm apart on each) no longer chain them into
# one. On eight workspaces of the two samples the objects' points are the same for any LINK_SPACING in 1.75-2.75.
LINK_NEIGHBOURS = 6
LINK_SPACING = 2.25
LINK_FLOOR_M = 0.02


def _components(points: np.ndarray, radius: float) -> np.ndarray:
    """Connected-component label [N] of points linked when closer than ``radius`` and, past :data:`LINK_FLOOR_M`,
    closer than :data:`LINK_SPACING` x the spacing of the denser of the two (see there)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    tree = cKDTree(points)
    pairs = tree.query_pairs(radius, output_type="ndarray")
    n = len(points)
    if len(pairs) and n > LINK_NEIGHBOURS:
        spacing = tree.query(points, LINK_NEIGHBOURS + 1)[0][:, -1]  # [N] (the first neighbour is the point itself)
        length = np.linalg.norm(points[pairs[:, 0]] - points[pairs[:, 1]], axis=1)
        reach = np.maximum(LINK_SPACING * np.minimum(spacing[pairs[:, 0]], spacing[pairs[:, 1]]), LINK_FLOOR_M)
        pairs = pairs[length < reach]
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    return connected_components(graph, directed=False)[1]


def find_objects(
    points: np.ndarray,
    plane: Plane | None = None,
    min_height: float = 0.006,
    max_height: float = 0.4,
    link_radius: float = 0.035,
    min_points: int = MIN_CLUSTER_POINTS,
    min_extent: float = 0.012,
    table_margin: float = 0.05,
    speck_fraction: float = 0.15,
    speck_height: float = 0.02,
) -> tuple[Plane, list[ObjectCluster]]:
    """(support plane, object clusters named ``object_<i>`` ordered by distance from the base origin).

    Keeps points between ``min_height`` and ``max_height`` above the plane that lie over the
    table (within ``table_margin`` of the plane inliers' xy bounding box; with fewer than :data:`MIN_TABLE_POINTS`
    of them, within :data:`NO_TABLE_REACH_M` of the base), links points closer than
    ``link_radius`` (and, past 2 cm, closer than about twice the denser one's point spacing: :func:`_components`), and
    keeps clusters with at least ``min_points`` points that rise at least
    ``min_extent`` above the plane (flat things on the table are not objects). A cluster that is both
    sparse (fewer than ``speck_fraction`` of the largest cluster's points) and low (top under
    ``speck_height``) is SfM noise on the table, not an object (seen on the sample: 12-13 points,
    1 cm high, beside objects of 100-200 points)."""
    pts = np.asarray(points, np.float64)
    plane = plane or fit_support_plane(pts)
    h = plane.height(pts)
    table = pts[plane.inliers]
    if len(table) >= MIN_TABLE_POINTS:
        lo = np.percentile(table[:, :2], 1, axis=0) - table_margin
        hi = np.percentile(table[:, :2], 99, axis=0) + table_margin
        over = np.all((pts[:, :2] >= lo) & (pts[:, :2] <= hi), axis=1)
    else:  # a table SfM saw no texture on: its extent is unknown
        over = np.hypot(pts[:, 0], pts[:, 1]) <= NO_TABLE_REACH_M
    keep = (h > min_height) & (h < max_height) & over
    cand = pts[keep]
    if len(cand) == 0:
        raise ObjectsError(
            "no object found: no points stand above the support plane; check that the objects are on the table "
            "and seen in the keyframes (or give --prompts / --masks)"
        )
    labels = _components(cand, link_radius)
    clusters = []
    for lab in np.unique(labels):
        p = cand[labels == lab]
        top = float(plane.height(p).max())
        if len(p) < min_points or top < min_extent:
            continue
        clusters.append(cluster_of(p, plane))
    if clusters:
        biggest = max(len(c.points) for c in clusters)
        clusters = [c for c in clusters if len(c.points) >= speck_fraction * biggest or c.height >= speck_height]
    if not clusters:
        raise ObjectsError(
            f"no object found: {len(cand)} points above the support plane but no cluster of >= {min_points} points "
            f"rising >= {min_extent * 1000:.0f} mm; capture more views of the objects (or give --prompts / --masks)"
        )
    clusters.sort(key=lambda c: float(np.linalg.norm(c.centroid[:2])))
    for i, c in enumerate(clusters):
        c.name = f"object_{i}"
    return plane, clusters


def name_clusters(clusters: list[ObjectCluster], names: Sequence[str], sparse_fraction: float = 0.15
                  ) -> list[ObjectCluster]:  # fmt: skip
    """Name clusters from ``names``: ``"banana"`` takes the next cluster in order of distance from
    the base; ``"banana=0.42,0.16"`` takes the cluster nearest to that base-frame (x, y). Returns
    only the named clusters, in the order of ``names``.

    When more clusters are found than names given, the surplus is taken from the sparse ones first (fewer than
    ``sparse_fraction`` of the largest cluster's points, sparsest first) before the plain names count off by
    distance: on the UR5e sample, 12 SfM noise points scattered 5-48 mm over the wood grain (tracks of 2-5 views,
    0.3-2.4 px reprojection against the model's 0.25 px median) lay nearer the base than the button (183 points),
    took its name, and the button's matting failed."""
    free = list(clusters)
    out: list[ObjectCluster | None] = [None] * len(names)
    # positioned names first, so that the plain ones take what is left in distance order
    for i, spec in enumerate(names):
        if "=" not in spec:
            continue
        name, _, where = spec.partition("=")
        try:
            xy = np.array([float(v) for v in where.split(",")])
            assert xy.shape == (2,)
        except (ValueError, AssertionError):
            raise ObjectsError(f"object name {spec!r}: expected name=x,y (base frame, metres)") from None
        if not free:
            raise ObjectsError(f"object {name!r}: no object left to name (found {len(clusters)})")
        j = int(np.argmin([np.linalg.norm(c.centroid[:2] - xy) for c in free]))
        if np.linalg.norm(free[j].centroid[:2] - xy) > 0.1:
            raise ObjectsError(f"object {name!r}: no object found within 10 cm of ({xy[0]:.3f}, {xy[1]:.3f})")
        out[i] = free.pop(j)
        out[i].name = name
    surplus = len(free) - sum("=" not in spec for spec in names)
    if surplus > 0 and free:
        biggest = max(len(c.points) for c in clusters)
        sparse = sorted((c for c in free if len(c.points) < sparse_fraction * biggest), key=lambda c: len(c.points))
        passed_over = {id(c) for c in sparse[:surplus]}
        free = [c for c in free if id(c) not in passed_over]
    for i, spec in enumerate(names):
        if "=" in spec:
            continue
        if not free:
            raise ObjectsError(
                f"object {spec!r}: only {len(clusters)} object(s) found on the table for {len(names)} names "
                f"({', '.join(names)}); give fewer names or capture the missing objects"
            )
        out[i] = free.pop(0)
        out[i].name = spec
    return [c for c in out if c is not None]

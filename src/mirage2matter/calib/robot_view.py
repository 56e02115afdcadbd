"""The robot as the capture saw it: where it lies in each keyframe, which SfM points are on it, and how well its
known surface agrees with the board's alignment.

Every real capture films the robot bolted to the table, at the joint state it had while filming (its
``capture_joints``). Once the board has placed the SfM scene in the base frame, the robot's link surfaces at that
state (robots.surface) are known exactly there, and they give three things:

- **Silhouettes** per keyframe (:func:`robot_silhouettes`): the pixels the robot covers, so the scene's Gaussians
  are never fitted to them (a frozen "ghost" robot in every generated frame otherwise).
- **The robot's SfM points** (:func:`robot_points`): points within a few millimetres of a link, or inside the robot's
  visual hull (every keyframe that sees the point sees the robot there). They are kept out of the scene's initial
  points and of the objects' clustering (the robot is the nearest "object" to the base otherwise).
- **A second alignment target** (:func:`fit_to_robot`): the paper's ICP on the base, extended to every visible link:
  rigid ICP of the robot's SfM points onto its surface, with the board corners as anchors. It reports how far the
  robot's surface lies from the board's alignment; a large disagreement means a wrong ``capture_joints`` or a board
  that moved.

A capture whose keyframes do not show the robot (an empty table, the robot elsewhere) has few SfM points on its
surface: :func:`robot_points` measures the fraction of the robot's visible surface the SfM reconstructed, and the
align stage uses the robot only when it was seen.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..geometry.camera import Camera
from ..geometry.icp import scaled_icp
from ..geometry.rotation import rotation_angle
from ..geometry.sim3 import Sim3
from ..robots import get_robot
from ..robots.capture_poses import CapturePoses
from ..robots.surface import LinkSurface, robot_surface, sample_surface

__all__ = ["Framing", "RobotFit", "RobotPoints", "SeenRobot", "fit_to_robot", "grow_mask", "robot_depth",
           "robot_depths", "robot_framing", "robot_points", "robot_silhouette", "robot_silhouettes", "seen_robot",
           "views_behind_robot", "visual_hull"]  # fmt: skip

# A point this close (m) to a link's surface is the robot's: SfM noise on a textured link at ~1 m is a few mm, and
# the link meshes are the model's, not the real casting (a few mm off in places).
ON_ROBOT_M = 0.01
# The robot was seen when at least this many SfM points (and this fraction of all) lie on its surface above the
# table (3 cm up: the base's bottom face lies on the table, whose points are not the robot's evidence). A robot's
# smooth paint gives SfM few features: the short robot sample (20 keyframes, 2,219 points) put 54 there; an empty
# table has none in mid-air where the arm would be.
SEEN_MIN_POINTS = 20
NEAR_ROBOT_M = 0.08  # "around the robot" for RobotPoints.on_fraction
# Below it, the robot's points lie beside its model: a wrong joint state. The right one gave 0.83-0.91 on the samples
# (the Panda's at 40 and 48 keyframes, the UR5e's), a first or second joint 0.1 rad off 0.52-0.78 (on_fraction); 0.85
# warned falsely (82 % at 48 keyframes) while the base's points counted. The Panda's third joint 0.1 rad off passes
# (0.81-0.86).
POSE_MIN_ON_FRACTION = 0.8
SEEN_POINT_FRACTION = 0.01
# A robot SfM found no points on (smooth white paint filmed from two sides: the first public real capture with the
# arm in view, 0 of 1,164 points) still counts as seen where it is framed and the keyframes did not see through it:
# its silhouette covers FRAMED_MIN of at least FRAMED_MIN_KEYFRAMES keyframes, and of the SfM observations inside
# those silhouettes (eroded by THROUGH_ERODE_PX), at most SEEN_THROUGH_MAX lie behind its surface by THROUGH_MARGIN_M.
# Where the table is empty the cameras see the board and table there: 1,810 of 1,886 observations (the empty-table
# sample, 20 keyframes); the robot sample's were 5 % of 458 (its edges; measured at full resolution), the real
# capture's none.
FRAMED_MIN = 0.01
FRAMED_MIN_KEYFRAMES = 2
SEEN_THROUGH_MAX = 0.5
THROUGH_MARGIN_M = 0.03
THROUGH_ERODE_PX = 1  # at the quarter scale framing is measured at: 4 px of the keyframe
THROUGH_MIN_OBSERVATIONS = 20  # fewer observations inside say nothing either way


def grow_mask(mask: np.ndarray, px: int) -> np.ndarray:
    """bool [H,W]: ``mask`` grown by ``px`` pixels (a square neighbourhood; 0: as it is)."""
    import cv2

    if px <= 0:
        return np.asarray(mask, bool)
    return cv2.dilate(np.asarray(mask, np.uint8), np.ones((2 * px + 1, 2 * px + 1), np.uint8)).astype(bool)


def robot_silhouette(camera: Camera, links: Sequence[LinkSurface], dilate_px: int = 0) -> np.ndarray:
    """bool [H,W]: the pixels ``camera`` (pinhole: its K, no lens) sees the robot's links in, whatever is in front
    of them, grown by ``dilate_px`` pixels. Triangles reaching behind the camera's near plane are left out."""
    import cv2

    mask = np.zeros((camera.height, camera.width), np.uint8)
    vm = camera.viewmat
    shift = 4  # sub-pixel vertices: 1/16 px
    for link in links:
        pc = link.vertices @ vm[:3, :3].T + vm[:3, 3]
        z = pc[:, 2]
        tri = link.faces[np.all(z[link.faces] > 0.01, axis=1)]
        if not len(tri):
            continue
        uv = (pc[:, :2] / z[:, None]) * [camera.K[0, 0], camera.K[1, 1]] + [camera.K[0, 2], camera.K[1, 2]]
        uv = uv - 0.5  # our pixel centres are at +0.5, OpenCV's at integers
        far = np.abs(uv).max(axis=1) > 4 * max(camera.width, camera.height)  # off-image vertices: fixed-point range
        tri = tri[~np.any(far[tri], axis=1)]
        # one triangle a call: fillPoly over many polygons fills their overlaps by parity, leaving holes
        for poly in np.round(uv[tri] * (1 << shift)).astype(np.int32):
            cv2.fillConvexPoly(mask, poly, 1, lineType=cv2.LINE_8, shift=shift)
    return grow_mask(mask, dilate_px)


def robot_silhouettes(cameras: Sequence[Camera], links: Sequence[LinkSurface], dilate_px: int = 0) -> list[np.ndarray]:
    """:func:`robot_silhouette` of each camera."""
    return [robot_silhouette(c, links, dilate_px) for c in cameras]


def visual_hull(points: np.ndarray, cameras: Sequence[Camera], silhouettes: Sequence[np.ndarray],
                min_views: int = 2) -> np.ndarray:
    """bool [N]: points that every camera seeing them (in front, inside the image) sees inside its silhouette, and
    at least ``min_views`` cameras see. Such a point is never seen by a pixel outside the robot: nothing but the
    robot can be learnt there."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    inside = np.ones(len(points), bool)
    seen = np.zeros(len(points), np.int64)
    for cam, sil in zip(cameras, silhouettes, strict=True):
        uv, z = cam.project(points)
        u, v = np.floor(uv[:, 0]).astype(np.int64), np.floor(uv[:, 1]).astype(np.int64)
        ok = (z > 0) & (u >= 0) & (v >= 0) & (u < cam.width) & (v < cam.height)
        hit = np.zeros(len(points), bool)
        hit[ok] = sil[v[ok], u[ok]]
        inside &= hit | ~ok
        seen += ok
    return inside & (seen >= min_views)


@dataclass
class SeenRobot:
    """align-scene's calib/robot.json and the robot's links at each joint state it held while filmed.

    pose_links      per pose (``robots.capture_poses``), the links at that pose (base frame)
    keyframe_pose   {keyframe: pose}; a keyframe not named holds the first pose
    """

    record: dict
    pose_links: list[list[LinkSurface]]
    keyframe_pose: dict[str, int]

    @property
    def links(self) -> list[LinkSurface]:
        """The links at the first joint state (``capture_joints``)."""
        return self.pose_links[0]

    def links_for(self, keyframe: str) -> list[LinkSurface]:
        """The links as keyframe ``keyframe`` saw them."""
        return self.pose_links[self.keyframe_pose.get(keyframe, 0)]

    def depths(self, cameras: Sequence[Camera]) -> list[np.ndarray]:
        """:func:`robot_depths` of each camera (named by its keyframe), the robot as that keyframe saw it."""
        samples: dict[int, np.ndarray] = {}
        out = []
        for cam in cameras:
            p = self.keyframe_pose.get(cam.name, 0)
            if p not in samples:
                samples[p] = sample_surface(self.pose_links[p], 0.003)[0]
            out.append(robot_depth(cam, samples[p]))
        return out


def seen_robot(record_file: Path) -> SeenRobot | None:
    """The robot as align-scene found it in the keyframes (calib/robot.json); None when they do not show it (or no
    alignment recorded it)."""

    if not record_file.is_file():
        return None
    record = json.loads(record_file.read_text(encoding="utf-8"))
    if not record.get("seen"):
        return None
    spec = get_robot(record["robot"])
    poses = CapturePoses.from_json(record)
    return SeenRobot(record, [robot_surface(spec, q) for q in poses.joints], dict(record.get("keyframe_pose") or {}))


def robot_depth(camera: Camera, samples_base: np.ndarray, close_px: int = 2) -> np.ndarray:
    """float32 [H,W]: the depth (m, along the optical axis) of the nearest robot surface each pixel of ``camera``
    (pinhole) sees, inf where it sees none. ``samples_base`` [M,3]: points on the robot's surface (sample_surface,
    a few mm apart), splatted with a z-buffer; a ``close_px`` minimum filter closes the gaps between them."""
    import cv2

    depth = np.full((camera.height, camera.width), np.inf, np.float32)
    uv, z = camera.project(samples_base)
    u, v = np.floor(uv[:, 0]).astype(np.int64), np.floor(uv[:, 1]).astype(np.int64)
    ok = (z > 0.01) & (u >= 0) & (v >= 0) & (u < camera.width) & (v < camera.height)
    np.minimum.at(depth, (v[ok], u[ok]), z[ok].astype(np.float32))
    if close_px > 0:  # erosion takes the minimum: the nearer surface wins across a gap
        depth = cv2.erode(depth, np.ones((2 * close_px + 1, 2 * close_px + 1), np.uint8))
    return depth


def robot_depths(cameras: Sequence[Camera], links: Sequence[LinkSurface]) -> list[np.ndarray]:
    """:func:`robot_depth` of each camera, from one sampling of the links (3 mm apart)."""
    samples, _ = sample_surface(links, 0.003)
    return [robot_depth(cam, samples) for cam in cameras]


def views_behind_robot(points_base: np.ndarray, cameras: Sequence[Camera], depths: Sequence[np.ndarray],
                       min_fraction: float = 0.05, margin_m: float = 0.01) -> list[bool]:
    """Per camera: does the robot stand in front of at least ``min_fraction`` of the object's points [N,3] (base
    frame) that the camera sees? ``depths``: :func:`robot_depths` at the capture joint state. Such a keyframe shows
    the robot where the object's projection falls (its mask would paint the robot onto the object): the objects
    stage leaves it out. The robot behind the object or beside it does not count: only surface nearer than the
    point by ``margin_m``. (On the robot sample: 51-100 % of a hidden object's points, 0-1 % of the others.)"""
    points_base = np.asarray(points_base, np.float64).reshape(-1, 3)
    out = []
    for cam, depth in zip(cameras, depths, strict=True):
        uv, z = cam.project(points_base)
        u, v = np.floor(uv[:, 0]).astype(np.int64), np.floor(uv[:, 1]).astype(np.int64)
        ok = (z > 0) & (u >= 0) & (v >= 0) & (u < cam.width) & (v < cam.height)
        out.append(bool(ok.any() and (depth[v[ok], u[ok]] < z[ok] - margin_m).mean() >= min_fraction))
    return out


@dataclass
class Framing:
    """How the keyframes frame the robot (:func:`robot_framing`).

    keyframes   keyframes the robot's silhouette covers FRAMED_MIN or more of
    inside      SfM observations in those keyframes inside its (eroded) silhouette
    through     of them, the ones whose point lies behind the robot's surface there: the keyframe saw through it
    """

    keyframes: int
    inside: int
    through: int

    @property
    def seen(self) -> bool:
        """Framed, and not seen through: the robot stands where the keyframes look."""
        contradicted = self.inside >= THROUGH_MIN_OBSERVATIONS and self.through > SEEN_THROUGH_MAX * self.inside
        return self.keyframes >= FRAMED_MIN_KEYFRAMES and not contradicted


def robot_framing(cameras: Sequence[Camera], links_of: Callable[[Camera], Sequence[LinkSurface]],
                  observations: Mapping[str, tuple[np.ndarray, np.ndarray]], scale: float = 0.25) -> Framing:
    """Which keyframes frame the robot, and whether what they observed there lies behind it. ``links_of(camera)``:
    the links as that keyframe saw them; ``observations``: {keyframe name: (xy [K,2] pixels, points [K,3] base
    frame)} (``sfm.colmap.load_observations``, moved to the base). Measured at ``scale`` of the keyframes."""
    framed = inside = through = 0
    samples: dict[int, np.ndarray] = {}
    for cam in cameras:
        links = links_of(cam)
        small = cam.scaled(scale)
        sil = robot_silhouette(small, links)
        if sil.mean() < FRAMED_MIN:
            continue
        framed += 1
        xy, points = observations.get(cam.name, (np.zeros((0, 2)), np.zeros((0, 3))))
        if not len(xy):
            continue
        core = ~grow_mask(~sil, THROUGH_ERODE_PX)
        u, v = np.floor(xy[:, 0] * scale).astype(np.int64), np.floor(xy[:, 1] * scale).astype(np.int64)
        ok = (u >= 0) & (v >= 0) & (u < small.width) & (v < small.height)
        hit = np.zeros(len(xy), bool)
        hit[ok] = core[v[ok], u[ok]]
        if not hit.any():
            continue
        if id(links) not in samples:
            samples[id(links)] = sample_surface(links, 0.003)[0]
        depth = robot_depth(small, samples[id(links)])
        _, z = small.project(points[hit])
        inside += int(hit.sum())
        through += int(np.sum(z > depth[v[hit], u[hit]] + THROUGH_MARGIN_M))
    return Framing(framed, inside, through)


@dataclass
class RobotPoints:
    """Which SfM points (base frame) are the robot's.

    on_robot         [N] bool: within ``ON_ROBOT_M`` of a link, or inside the robot's visual hull
    distance         [N] metres from the nearest link surface
    on_surface       points within ON_ROBOT_M of a link and 3 cm or more above the table
    seen_fraction    of the robot's surface the cameras see, the fraction the SfM reconstructed (5 mm cells with a
                     point within ON_ROBOT_M)
    seen             the capture shows the robot: on_surface >= SEEN_MIN_POINTS and SEEN_POINT_FRACTION of the points
    per_link         {link: seen fraction}
    on_fraction      of the points above the table within NEAR_ROBOT_M of a link the joints move (not the base),
                     the fraction on its surface: near 1 when the joint state is right; a robot posed elsewhere
                     leaves its points beside the model's surface (the two-pose Panda sample, 40 keyframes: 0.89 at
                     its capture joints, 0.77 / 0.75 / 0.55 with joint 2 0.1 rad, joint 1 0.1 or 0.35 rad off; 48
                     keyframes: 0.83, 0.69 / 0.78 / 0.55; the UR5e sample: 0.91, against 0.34-0.84)
    """

    on_robot: np.ndarray
    distance: np.ndarray
    on_surface: int
    seen_fraction: float
    seen: bool
    per_link: dict[str, float] = field(default_factory=dict)
    on_fraction: float = 1.0


def _visible_samples(samples: np.ndarray, cameras: Sequence[Camera]) -> np.ndarray:
    """[M] bool: surface samples inside at least two cameras' images, in front of them."""
    n = np.zeros(len(samples), np.int64)
    for cam in cameras:
        uv, z = cam.project(samples)
        n += (z > 0) & (uv[:, 0] >= 0) & (uv[:, 1] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] < cam.height)
    return n >= 2


def robot_points(points: np.ndarray, links: Sequence[LinkSurface], cameras: Sequence[Camera],
                 silhouettes: Sequence[np.ndarray] | None = None, on_robot_m: float = ON_ROBOT_M) -> RobotPoints:
    """Classify SfM points [N,3] (base frame) against the robot's links at the capture joint state."""
    from scipy.spatial import cKDTree

    points = np.asarray(points, np.float64).reshape(-1, 3)
    samples, owner = sample_surface(links, 0.005)
    dist, nearest = cKDTree(samples).query(points, distance_upper_bound=0.5, workers=-1) if len(points) else \
        (np.zeros(0), np.zeros(0, np.int64))  # fmt: skip
    dist = np.minimum(dist, 0.5)
    moves = np.array([not link.fixed for link in links])[owner[np.minimum(nearest, len(samples) - 1)]]
    near = dist <= on_robot_m
    if silhouettes is not None and len(points):
        near |= visual_hull(points, cameras, silhouettes)
    # above the table only: the base's bottom face lies on the board, whose points are not the robot's evidence
    visible = _visible_samples(samples, cameras) & (samples[:, 2] > 0.03)
    covered = np.zeros(len(samples), bool)
    if len(points):
        d, _ = cKDTree(points).query(samples, distance_upper_bound=on_robot_m, workers=-1)
        covered = np.isfinite(d)
    frac = float(covered[visible].mean()) if visible.any() else 0.0
    per_link = {}
    for i, link in enumerate(links):
        sel = visible & (owner == i)
        if sel.sum() >= 20:
            per_link[link.link] = float(covered[sel].mean())
    above = points[:, 2] > 0.03
    on_surface = int(np.sum((dist <= on_robot_m) & above))
    seen = on_surface >= max(SEEN_MIN_POINTS, SEEN_POINT_FRACTION * len(points))
    # the joint state shows in the links it moves: the base's points (SfM noise 1-2 cm off its smooth paint) only
    # dilute the measure (the sample at 48 keyframes: 82 % of all, the base's 17 of 22 points off)
    moving = above & moves
    on_moving = int(np.sum((dist <= on_robot_m) & moving))
    on_fraction = on_moving / max(int(np.sum((dist <= NEAR_ROBOT_M) & moving)), 1)
    return RobotPoints(near, dist, on_surface, frac, seen, per_link, on_fraction)


@dataclass
class RobotFit:
    """The robot's surface as a second alignment target, after the board's alignment.

    correction      base -> base rigid transform that ICP found (identity: the board's alignment agrees)
    rotation_deg    its rotation angle
    translation_mm  its translation at the robot (the shift of the points it moved, median)
    rms_before_mm   robot points to the surface (trimmed RMS) with the board's alignment
    rms_after_mm    the same after the correction
    corner_rms_mm   the board's corners after the correction (the board alone: AlignResult.corner_rms_mm)
    points          robot points used
    """

    correction: Sim3
    rotation_deg: float
    translation_mm: float
    rms_before_mm: float
    rms_after_mm: float
    corner_rms_mm: float
    points: int

    def to_json(self) -> dict:
        keys = ("rotation_deg", "translation_mm", "rms_before_mm", "rms_after_mm", "corner_rms_mm", "points")
        return {"correction": self.correction.to_json(), **{k: getattr(self, k) for k in keys}}


def _trimmed_rms(d: np.ndarray, keep: float = 0.8) -> float:
    d = np.sort(np.asarray(d))
    d = d[: max(1, int(round(keep * len(d))))]
    return float(np.sqrt(np.mean(d**2)))


def fit_to_robot(points_base: np.ndarray, links: Sequence[LinkSurface], anchors: tuple[np.ndarray, np.ndarray],
                 anchor_weight: float = 1.0) -> RobotFit:
    """Rigid ICP of the robot's SfM points [N,3] (base frame, by the board) onto its link surfaces, with the board's
    triangulated corners (base frame) held to their known places (``anchors`` = (triangulated [K,3], known [K,3]))
    at ``anchor_weight`` times the surface's total weight. Scale stays the board's: the robot's meshes are a model,
    the board is printed to size."""
    from scipy.spatial import cKDTree

    points_base = np.asarray(points_base, np.float64).reshape(-1, 3)
    samples, _ = sample_surface(links, 0.002)
    before = cKDTree(samples).query(points_base, workers=-1)[0]
    result = scaled_icp(points_base, samples, with_scale=False, trim_fraction=0.8, max_distance=3 * ON_ROBOT_M,
                        anchors=anchors, anchor_weight=anchor_weight)  # fmt: skip
    corr = result.sim3
    moved = corr.apply(points_base)
    after = cKDTree(samples).query(moved, workers=-1)[0]
    corners = corr.apply(np.asarray(anchors[0], np.float64))
    corner_rms = float(1000 * np.sqrt(np.mean(np.sum((corners - np.asarray(anchors[1])) ** 2, axis=1))))
    return RobotFit(corr, float(np.degrees(rotation_angle(corr.rotation))),
                    float(1000 * np.median(np.linalg.norm(moved - points_base, axis=1))),
                    1000 * _trimmed_rms(before), 1000 * _trimmed_rms(after), corner_rms, len(points_base))  # fmt: skip

"""The sample robot's own look: each link's model mesh with paint, rubber and wear that the model's default materials
do not have, so a reconstruction that draws the robot as the capture saw it can be told from one that draws the
model's flat meshes (the fallback).

Every link is textured in its own frame (box projection: each triangle takes the texture of the link-frame plane its
normal faces most), so the same look follows the link wherever forward kinematics puts it: in the video, filmed at
the capture joint state, and in the ground-truth world while the robot moves.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import trimesh

from ..robots.kinematics import RobotKinematics
from ..robots.spec import RobotSpec
from ..robots.surface import LinkSurface, robot_surface
from .sample_assets import PlacedAsset, _fbm, _grain, _textured, _to_image

__all__ = ["ROBOT_LOOK_PREFIX", "capture_joints_for", "robot_look_assets", "robot_look_meshes", "second_pose_for"]

ROBOT_LOOK_PREFIX = "robot_"  # asset names: robot_<link>
_TILE = 512  # texture pixels per projection tile (three tiles side by side)
# Paint (RGB 0..255) by the link's place in the chain: a warm orange arm, graphite joints' caps every other link,
# a dark hand and rubber fingers; none of it is the model's white / black.
_PAINT = ((222, 120, 40), (70, 74, 82), (222, 120, 40), (230, 190, 60), (222, 120, 40), (70, 74, 82))
_HAND = (52, 56, 64)
_RUBBER = (28, 28, 30)


def capture_joints_for(spec: RobotSpec) -> np.ndarray:
    """The arm joints [n_arm] the sample films the robot at: home, turned 0.35 rad about the base's vertical axis
    (away from the board beside it), so that the home pose, the default of ``capture_joints``, is not the truth."""
    q = np.asarray(spec.home, dtype=np.float64).copy()
    lo, hi = spec.joint_limits[0]
    q[0] = float(np.clip(q[0] - 0.35, lo, hi))
    return q


# The pose the robot moves to half-way through the video (`m2m sample make`; `--one-pose` keeps it still). The orbit's
# second half films the robot from its front and left (+y), 0.5-0.85 m up, looking down at the table; at the first pose
# the upper arm, wrist and hand stand above its view. The second pose brings the hand down, low over the free table left
# of the banana and the button, its approach axis tilted from straight down (toward the base by ``tilt`` rad, in the
# vertical plane through the base and the hand), so that the faces the head camera sees at the first pose face the
# orbit's cameras, and the room the first pose hid is in view again. Checked for the bundled robots
# (tests/sample/test_sample_second_pose.py): clear of the table, the objects, the board and the robot itself.
SECOND_POSE_HAND_AT = (0.45, 0.4, 0.16)  # the end-effector link's origin, base frame (m)
SECOND_POSE_TILT = 0.8


def second_pose_for(spec: RobotSpec, hand_at=SECOND_POSE_HAND_AT, tilt: float = SECOND_POSE_TILT) -> np.ndarray:
    """The arm joints [n_arm] the sample's robot moves to half-way through the video, to show the orbit what the
    first pose (:func:`capture_joints_for`) hid: inverse kinematics of the end-effector link at ``hand_at`` with its
    approach axis tilted ``tilt`` rad from straight down toward the base, from home turned toward ``hand_at`` (the
    solution nearest it; rounded to 1e-4 rad). Home turned so, when the robot cannot reach it."""
    from scipy.optimize import least_squares

    kin = RobotKinematics(spec.model)
    n, _ = kin.chain(spec.ee_link)
    lo, hi = (np.asarray(v, dtype=np.float64) for v in zip(*spec.joint_limits[: spec.n_arm], strict=True))
    home = np.asarray(spec.home, dtype=np.float64)

    def pose(q: np.ndarray) -> np.ndarray:
        return kin.link_pose(np.r_[q, np.zeros(n - spec.n_arm)][:n] if n > spec.n_arm else q[:n], spec.ee_link)

    target = np.asarray(hand_at, dtype=np.float64)
    at_home = pose(home)[:3, 3]
    seed = home.copy()
    turn = np.arctan2(target[1], target[0]) - np.arctan2(at_home[1], at_home[0])
    seed[0] = float(np.clip(home[0] + turn, lo[0], hi[0]))
    inward = -target[:2] / np.linalg.norm(target[:2])  # horizontal, from the hand toward the base
    approach = np.r_[np.sin(tilt) * inward, -np.cos(tilt)]
    approach_ee = np.asarray(spec.tcp_approach, dtype=np.float64)

    def residual(q: np.ndarray) -> np.ndarray:
        T = pose(q)
        return np.concatenate([T[:3, 3] - target, 0.3 * (T[:3, :3] @ approach_ee - approach), 0.01 * (q - seed)])

    sol = least_squares(residual, seed, bounds=(lo, hi), xtol=1e-10, ftol=1e-10)
    if np.linalg.norm(sol.fun[:3]) > 0.01 or np.linalg.norm(sol.fun[3:6]) > 0.3 * 0.1:
        return seed  # out of reach
    return np.clip(np.round(sol.x, 4), lo, hi) + 0.0  # + 0.0: no -0.0 in the files


def _paint(spec: RobotSpec, link: str, index: int) -> tuple[tuple[int, int, int], float]:
    """(base colour, wear amount) of a link."""
    if link in spec.finger_links:
        return _RUBBER, 0.25
    if link == spec.ee_link or index >= len(spec.arm_joints) + 1:
        return _HAND, 0.5
    return _PAINT[index % len(_PAINT)], 1.0


def _texture(rng: np.random.Generator, colour: tuple[int, int, int], wear: float) -> np.ndarray:
    """[_TILE, 3 * _TILE, 3] float 0..255: paint with a mottled finish, scuffs, thin panel lines and grain."""
    h, w = _TILE, 3 * _TILE
    shade = 1.0 + 0.08 * _fbm(rng, h, w, (6, 14, 40)) * wear
    scuffs = np.clip(_fbm(rng, h, w, (10, 30)) - 1.6, 0, None)  # rare dark patches
    shade -= 0.35 * scuffs * wear
    img = np.asarray(colour, np.float32)[None, None] * np.clip(shade, 0.3, 1.3)[..., None]
    # panel lines and small dark screws: texture for SfM and for the eye, fixed in the link's frame
    for _ in range(int(10 * wear) + 2):
        if rng.random() < 0.5:
            r = int(rng.integers(0, h))
            img[r : r + 2, :] *= 0.55
        else:
            c = int(rng.integers(0, w))
            img[:, c : c + 2] *= 0.55
    for _ in range(int(40 * wear) + 6):
        r, c = int(rng.integers(4, h - 4)), int(rng.integers(4, w - 4))
        img[r - 3 : r + 3, c - 3 : c + 3] = (30, 30, 34)
    return img + _grain(rng, h, w, 4.0)


def _box_uv(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unshared vertices [3F,3], faces [F,3] and uv [3F,2]: each triangle projected onto the link-frame plane its
    normal faces most, into that axis' third of the texture, scaled by the link's bounding box."""
    tri = vertices[faces]  # [F,3,3]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    axis = np.argmax(np.abs(n), axis=1)  # [F]
    lo, hi = vertices.min(0), vertices.max(0)
    span = float(np.max(hi - lo)) + 1e-9
    plane = np.array([[1, 2], [0, 2], [0, 1]])[axis]  # the two in-plane coordinates
    a = np.take_along_axis(tri, plane[:, None, 0:1].repeat(3, 1), axis=2)[..., 0]
    b = np.take_along_axis(tri, plane[:, None, 1:2].repeat(3, 1), axis=2)[..., 0]
    a = (a - lo[plane[:, 0]][:, None]) / span
    b = (b - lo[plane[:, 1]][:, None]) / span
    u = (axis[:, None] + 0.02 + 0.96 * a) / 3.0
    v = 0.02 + 0.96 * b
    uv = np.stack([u, v], axis=-1).reshape(-1, 2)
    return tri.reshape(-1, 3), np.arange(3 * len(faces)).reshape(-1, 3), uv


def robot_look_meshes(spec: RobotSpec, links: Sequence[LinkSurface], seed: int = 0) -> dict[str, trimesh.Trimesh]:
    """The textured mesh of each link, in the link's own frame: {link name: trimesh with TextureVisuals}."""
    out = {}
    for i, link in enumerate(links):
        rng = np.random.default_rng([int(seed), 7013, i])
        colour, wear = _paint(spec, link.link, i)
        v, f, uv = _box_uv(link.vertices_link, link.faces)
        out[link.link] = _textured(v, f, uv, _to_image(_texture(rng, colour, wear)), f"{ROBOT_LOOK_PREFIX}{link.link}")
    return out


def robot_look_assets(spec: RobotSpec, q: Sequence[float], seed: int = 0) -> list[PlacedAsset]:
    """The robot at joint state ``q`` as static textured assets (category "robot"), one per link, named
    ``robot_<link>`` and placed at the link's pose."""
    links = robot_surface(spec, q)
    meshes = robot_look_meshes(spec, links, seed)
    return [PlacedAsset(f"{ROBOT_LOOK_PREFIX}{link.link}", meshes[link.link], link.T_base_link.copy(), "robot",
                        {"link": link.link}) for link in links]  # fmt: skip

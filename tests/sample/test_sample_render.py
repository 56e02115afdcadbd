"""The sample's Genesis rendering layer: camera convention, determinism, held board, hand-eye poses.

One scene for the whole module (building a Genesis scene takes tens of seconds): flat-coloured
marker spheres at known points, the Panda, and a board whose printed face has four coloured
quadrants. Lighting is ambient only, so every surface renders in its own colour.
"""

from __future__ import annotations

import math
from collections.abc import Iterator

import numpy as np
import pytest
import trimesh
from PIL import Image

from mirage2matter.geometry.camera import look_at_pose
from mirage2matter.sample.render import (
    ROBOT,
    RenderConfig,
    SampleRenderer,
    default_T_base_headcam,
    sample_handeye_configurations,
)
from mirage2matter.world.sample_assets import PlacedAsset

HOME = np.asarray(ROBOT.home)

pytest.importorskip("genesis")

MARKER_RADIUS = 0.012
# Saturated colours no other surface has (the robot is white / grey / black, the board's are below).
MARKERS = {
    "m_magenta": ((0.60, -0.30, 0.02), (255, 0, 255)),
    "m_cyan": ((0.45, -0.50, 0.10), (0, 255, 255)),
    "m_orange": ((0.80, -0.10, 0.20), (255, 128, 0)),
    "m_purple": ((0.35, -0.25, 0.05), (128, 0, 255)),
    "m_pink": ((0.70, -0.45, 0.30), (255, 0, 128)),
}
BOARD_SIZE = (0.20, 0.15, 0.004)
# Printed-face quadrants as seen in the texture image: (row half, column half) -> colour.
QUADRANTS = {(0, 0): (255, 0, 0), (0, 1): (0, 255, 0), (1, 0): (0, 0, 255), (1, 1): (255, 255, 0)}


def _rigid(t: tuple[float, float, float]) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = t
    return T


def _marker(rgb: tuple[int, int, int]) -> trimesh.Trimesh:
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=MARKER_RADIUS)
    mesh.visual.vertex_colors = np.tile([*rgb, 255], (len(mesh.vertices), 1))
    return mesh


def _quadrant_image(width: int = 200, height: int = 150) -> np.ndarray:
    img = np.zeros((height, width, 3), np.uint8)
    for (r, c), rgb in QUADRANTS.items():
        img[r * height // 2 : (r + 1) * height // 2, c * width // 2 : (c + 1) * width // 2] = rgb
    return img


def _board_mesh(size: tuple[float, float, float], image: np.ndarray) -> trimesh.Trimesh:
    """Box centred at the origin; the +z face shows ``image`` (row 0 at +y, column 0 at -x), the
    other faces its top-left pixel. Corners are duplicated per face so each face has its own uvs."""
    sx, sy, sz = (0.5 * s for s in size)
    h, w = image.shape[:2]
    verts: list[list[float]] = []
    uvs: list[tuple[float, float]] = []
    faces: list[list[int]] = []

    def quad(points: list[list[float]], uv: list[tuple[float, float]]) -> None:
        k = len(verts)
        verts.extend(points)
        uvs.extend(uv)
        faces.extend([[k, k + 1, k + 2], [k, k + 2, k + 3]])

    quad([[-sx, -sy, sz], [sx, -sy, sz], [sx, sy, sz], [-sx, sy, sz]], [(0, 0), (1, 0), (1, 1), (0, 1)])
    corner = [(0.5 / w, 1 - 0.5 / h)] * 4
    quad([[-sx, -sy, -sz], [-sx, sy, -sz], [sx, sy, -sz], [sx, -sy, -sz]], corner)
    quad([[-sx, -sy, -sz], [sx, -sy, -sz], [sx, -sy, sz], [-sx, -sy, sz]], corner)
    quad([[sx, sy, -sz], [-sx, sy, -sz], [-sx, sy, sz], [sx, sy, sz]], corner)
    quad([[sx, -sy, -sz], [sx, sy, -sz], [sx, sy, sz], [sx, -sy, sz]], corner)
    quad([[-sx, sy, -sz], [-sx, -sy, -sz], [-sx, -sy, sz], [-sx, sy, sz]], corner)
    mesh = trimesh.Trimesh(np.array(verts), np.array(faces), process=False)
    mesh.visual = trimesh.visual.TextureVisuals(uv=np.array(uvs), image=Image.fromarray(image))
    return mesh


def _project(K: np.ndarray, T_world_cam: np.ndarray, X_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels [N,2] (our convention) and camera depths [N] of world points [N,3]."""
    viewmat = np.linalg.inv(T_world_cam)
    Xc = X_world @ viewmat[:3, :3].T + viewmat[:3, 3]
    uvw = Xc @ K.T
    return uvw[:, :2] / uvw[:, 2:3], Xc[:, 2]


def _colour_mask(rgb: np.ndarray, colour: tuple[int, int, int], tol: int = 40) -> np.ndarray:
    return np.all(np.abs(rgb.astype(np.int32) - np.array(colour)) <= tol, axis=-1)


def _polygon_mask(uv: np.ndarray, width: int, height: int) -> np.ndarray:
    u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    edges = zip(uv, np.roll(uv, -1, axis=0), strict=True)
    cross = np.stack([(q[0] - p[0]) * (v - p[1]) - (q[1] - p[1]) * (u - p[0]) for p, q in edges])
    return np.all(cross >= 0, axis=0) | np.all(cross <= 0, axis=0)


def _with_roll(T_world_cam: np.ndarray, deg: float) -> np.ndarray:
    a = math.radians(deg)
    R = np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])
    T = T_world_cam.copy()
    T[:3, :3] = T[:3, :3] @ R
    return T


@pytest.fixture(scope="module")
def renderer(tmp_path_factory: pytest.TempPathFactory) -> Iterator[SampleRenderer]:
    assets = [PlacedAsset(name, _marker(rgb), _rigid(pos), "object") for name, (pos, rgb) in MARKERS.items()]
    board = PlacedAsset("board", _board_mesh(BOARD_SIZE, _quadrant_image()), np.eye(4), "board")
    config = RenderConfig(ambient=(1.0, 1.0, 1.0), lights=(), background=(0.2, 0.2, 0.2), shadow=False)
    workdir = tmp_path_factory.mktemp("render")
    with SampleRenderer(assets, config, with_robot=True, held_board=board, workdir=workdir) as r:
        yield r


def test_config_intrinsics() -> None:
    """Vertical fov -> fx = fy; principal point at the image centre; fy given -> the fov Genesis gets."""
    K = RenderConfig(width=640, height=480, fov_deg=50.0).K
    np.testing.assert_allclose(K, [[514.6816609, 0, 320], [0, 514.6816609, 240], [0, 0, 1]], atol=1e-6)
    cfg = RenderConfig(width=320, height=240, fy=300.0)
    assert cfg.K[0, 0] == cfg.K[1, 1] == 300.0 and (cfg.K[0, 2], cfg.K[1, 2]) == (160.0, 120.0)
    assert RenderConfig(width=320, height=240, fov_deg=cfg.effective_fov_deg).focal == pytest.approx(300.0)


# Two views of the markers, rolled so that an x/y swap or a flip cannot pass by symmetry.
MARKER_VIEWS = [
    _with_roll(look_at_pose(np.array([1.3, -0.9, 0.8]), np.array([0.55, -0.3, 0.12])), 12.0),
    _with_roll(look_at_pose(np.array([0.2, -1.1, 0.5]), np.array([0.6, -0.3, 0.12])), -20.0),
]


@pytest.mark.parametrize("view", range(len(MARKER_VIEWS)))
def test_projection_convention(renderer: SampleRenderer, view: int) -> None:
    """Marker centroids land within a pixel of K @ viewmat @ X (OpenCV axes, centres at +0.5),
    and the depth image holds planar depth."""
    renderer.set_joints(HOME)
    T_world_cam = MARKER_VIEWS[view]
    rgb, depth = renderer.render_rgbd(T_world_cam)
    assert rgb.shape == (renderer.size[1], renderer.size[0], 3) and rgb.dtype == np.uint8
    f = renderer.K[0, 0]
    for name, (pos, colour) in MARKERS.items():
        (uv,), (z,) = _project(renderer.K, T_world_cam, np.array([pos]))
        mask = _colour_mask(rgb, colour)
        v, u = np.nonzero(mask)
        assert len(u) > 0, f"{name} not rendered"
        centroid = np.array([u.mean(), v.mean()]) + 0.5  # pixel centres at +0.5
        # Measured <= 0.15 px; a half-pixel offset (0.5 px in u or v) fails.
        assert np.linalg.norm(centroid - uv) < 0.3, f"{name}: centroid {centroid} vs projection {uv}"
        # A whole sphere, not a partly hidden one: the area matches the projected disc.
        expected_area = math.pi * (f * MARKER_RADIUS / z) ** 2
        assert 0.7 * expected_area < mask.sum() < 1.3 * expected_area, name
        # Planar depth: the sphere's front point is at z - r along the optical axis.
        d = depth[int(uv[1]), int(uv[0])]
        assert abs(d - (z - MARKER_RADIUS)) < 2e-3, f"{name}: depth {d} vs {z - MARKER_RADIUS}"
    assert np.isinf(depth).any()  # the background reads as "nothing"


def test_render_is_deterministic(renderer: SampleRenderer) -> None:
    renderer.set_joints(HOME)
    a = renderer.render(MARKER_VIEWS[0])
    other = renderer.render(MARKER_VIEWS[1])
    b = renderer.render(MARKER_VIEWS[0])
    assert np.array_equal(a, b)
    assert not np.array_equal(a, other)


def _board_view(renderer: SampleRenderer) -> np.ndarray:
    """A camera 0.45 m in front of the held board's printed face, a little off its normal."""
    T_base_board = renderer.T_base_board
    a, b, n = (T_base_board[:3, :3] @ renderer.board_axes_obj).T
    centre = renderer.board_corners_base().mean(axis=0)
    eye = centre + 0.45 * (n + 0.25 * a - 0.2 * b) / np.linalg.norm(n + 0.25 * a - 0.2 * b)
    return look_at_pose(eye, centre, up=b)


@pytest.mark.parametrize("q", [HOME, np.array([0.5, -0.3, -0.3, -2.0, 0.4, 2.1, 0.3])])
def test_held_board_follows_the_hand(renderer: SampleRenderer, q: np.ndarray) -> None:
    """The board is drawn at T_base_hand @ T_hand_board with its texture the right way round,
    and the arm is drawn where Genesis' forward kinematics puts it."""
    renderer.set_joints(q)
    np.testing.assert_allclose(renderer.get_joints()[:7], q, atol=1e-6)
    T_world_cam = _board_view(renderer)
    rgb = renderer.render(T_world_cam)
    W, H = renderer.size
    corners_base = renderer.board_corners_base()
    np.testing.assert_allclose(
        corners_base,
        renderer.board_corners_obj @ renderer.T_base_board[:3, :3].T + renderer.T_base_board[:3, 3],
    )
    uv, _ = _project(renderer.K, T_world_cam, corners_base)
    polygon = _polygon_mask(uv, W, H)
    board = np.zeros((H, W), bool)
    for colour in QUADRANTS.values():
        board |= _colour_mask(rgb, colour)
    iou = (board & polygon).sum() / (board | polygon).sum()
    assert iou > 0.9, f"board IoU {iou:.3f}"
    # Each quadrant's centre shows its colour: catches mirrored or flipped textures.
    sx, sy, sz = (0.5 * s for s in BOARD_SIZE)
    for (r, c), colour in QUADRANTS.items():
        p_obj = np.array([(-0.5 + c) * sx, (0.5 - r) * sy, sz])  # row 0 at +y, column 0 at -x
        p_base = renderer.T_base_board[:3, :3] @ p_obj + renderer.T_base_board[:3, 3]
        ((u, v),), _ = _project(renderer.K, T_world_cam, p_base[None])
        assert _colour_mask(rgb[int(v), int(u)][None], colour)[0], f"quadrant {(r, c)}: {rgb[int(v), int(u)]}"
    # The rendered arm matches FK: a point inside the hand body and one on link 4 are robot pixels.
    robot = renderer.render_mask(T_world_cam, "robot")
    for link, p_link in (("hand", (0.0, 0.0, 0.03)), ("link4", (0.0, 0.0, 0.0))):
        T = renderer.T_base_link(link)
        ((u, v),), _ = _project(renderer.K, T_world_cam, (T[:3, :3] @ np.array(p_link) + T[:3, 3])[None])
        if 0 <= u < W and 0 <= v < H:
            assert robot[int(v), int(u)], f"{link} origin not drawn as robot"


def test_handeye_configurations(renderer: SampleRenderer) -> None:
    """Sampled configurations keep the board in view and facing the head camera, within the joint
    limits, without self-collision, rotating about non-parallel axes; deterministic per seed."""
    T_base_headcam = default_T_base_headcam()
    qs = sample_handeye_configurations(15, 0, T_base_headcam, renderer)
    assert len(qs) >= 15
    lo, hi = renderer.joint_limits
    W, H = renderer.size
    R_base_board = []
    for q in qs:
        assert q.shape == (9,) and np.all(q >= lo - 1e-6) and np.all(q <= hi + 1e-6)
        renderer.set_joints(q)
        assert not renderer.self_collision() and not renderer.board_intersects_arm()
        corners = renderer.board_corners_base()
        uv, z = _project(renderer.K, T_base_headcam, corners)
        assert np.all(z > 0.1)
        assert np.all(uv >= 10) and np.all(uv[:, 0] <= W - 10) and np.all(uv[:, 1] <= H - 10)
        n_base = renderer.T_base_board[:3, :3] @ renderer.board_axes_obj[:, 2]
        to_cam = T_base_headcam[:3, 3] - corners.mean(axis=0)
        assert n_base @ to_cam / np.linalg.norm(to_cam) > math.cos(math.radians(60.0))
        R_base_board.append(renderer.T_base_board[:3, :3])
    # Rotation axes of the relative motions: not all parallel (Tsai-Lenz needs two non-parallel).
    axes = []
    for i in range(len(qs) - 1):
        R = R_base_board[i].T @ R_base_board[i + 1]
        w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
        assert np.linalg.norm(w) > 0.05  # a real rotation between consecutive poses (> ~3 degrees)
        axes.append(w / np.linalg.norm(w))
    axes = np.stack(axes)
    assert np.abs(axes @ axes.T).min() < math.cos(math.radians(45.0))
    # The board is really visible in the last one (the sampler checks each with a segmentation render).
    board = renderer.render_mask(T_base_headcam, "board")
    assert board.sum() > 0.5 * _polygon_mask(uv, W, H).sum()
    again = sample_handeye_configurations(15, 0, T_base_headcam, renderer)
    assert len(again) == len(qs) and all(np.array_equal(a, b) for a, b in zip(qs, again, strict=True))


def test_board_arm_intersection_check(renderer: SampleRenderer) -> None:
    """The board does not collide in Genesis; the sampler's own check sees a board through the arm."""
    renderer.set_joints(HOME)
    assert not renderer.board_intersects_arm()
    mount = renderer.T_hand_board
    try:
        through_wrist = mount.copy()
        through_wrist[:3, 3] = -mount[:3, :3] @ renderer.board_corners_obj.mean(axis=0)  # face centre at the hand
        renderer.T_hand_board = through_wrist
        assert renderer.board_intersects_arm()
    finally:
        renderer.T_hand_board = mount

"""Rendering layer of the bundled sample: one Genesis rasterizer scene, a camera in our convention.

The scene holds the placed assets (textured meshes, robot-base frame = Genesis world) and, for the
hand-eye images, the robot (base at the origin; the Franka Panda by default) holding a board between its fingers.
It is built by the package's scene builder (``mirage2matter.sim.scene``), as the ground-truth world that re-renders
the sample is, so their pixels agree; Genesis' camera conventions are converted there.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType

import numpy as np
import trimesh

from mirage2matter.geometry.camera import look_at_pose
from mirage2matter.geometry.rotation import axis_angle_to_matrix, rotation_angle
from mirage2matter.geometry.sim3 import invert_rigid
from mirage2matter.robots import DEFAULT_ROBOT, RobotSpec, get_robot
from mirage2matter.sim.scene import RenderScene, SceneLook, pos_quat, pose_from
from mirage2matter.world.sample_assets import PlacedAsset

__all__ = [
    "ROBOT",
    "HandeyeCheck",
    "RenderConfig",
    "SampleRenderer",
    "board_face",
    "check_handeye_configuration",
    "default_T_base_headcam",
    "default_T_hand_board",
    "sample_handeye_configurations",
]

ROBOT = get_robot(DEFAULT_ROBOT)  # the sample's default robot (model bundled with genesis-world)
# Where the fingers hold the board's edge: this far (m) behind the tool centre along the approach axis. The
# Franka hand's fingertip pads span 0.094..0.111 m along its z, its tool centre is at 0.1034: the edge at 0.10
# is gripped over ~1.1 cm.
BOARD_GRIP_EDGE_DEPTH = 0.0034
# Inner face of a Franka fingertip pad sits ~1.5 mm from the finger joint's zero, so the joint value that
# just touches a board of thickness t is t/2 - 1.5 mm (clipped to the joint range; visual only, the board does
# not collide).
_PAD_INSET = 0.0015


# ---- configuration -------------------------------------------------------------------------------
@dataclass
class RenderConfig(SceneLook):
    """Camera and look of a :class:`SampleRenderer`: the scene's look (:class:`~mirage2matter.sim.scene.SceneLook`:
    ambient, lights, background, shadow, near, far; the sample's by default) and one pinhole camera.

    width, height   image size in pixels
    fov_deg         vertical field of view in degrees; ignored when ``fy`` is given
    fy              focal length in pixels (fx = fy; principal point at the image centre)
    Anti-aliasing is fixed at 4x MSAA by Genesis' offscreen rasterizer.
    """

    width: int = 640
    height: int = 480
    fov_deg: float = 50.0
    fy: float | None = None

    @property
    def focal(self) -> float:
        """fx = fy in pixels."""
        if self.fy is not None:
            return float(self.fy)
        return 0.5 * self.height / math.tan(math.radians(0.5 * self.fov_deg))

    @property
    def effective_fov_deg(self) -> float:
        """Vertical field of view in degrees (from ``fy`` when given), as Genesis takes it."""
        return math.degrees(2.0 * math.atan(0.5 * self.height / self.focal))

    @property
    def K(self) -> np.ndarray:
        """[3,3] intrinsics, pixel centres at +0.5 (principal point at W/2, H/2)."""
        f = self.focal
        return np.array([[f, 0.0, 0.5 * self.width], [0.0, f, 0.5 * self.height], [0.0, 0.0, 1.0]])


# ---- small geometry helpers ----------------------------------------------------------------------
def default_T_base_headcam(
    eye: tuple[float, float, float] = (-0.1, 0.45, 0.95), target: tuple[float, float, float] = (0.5, 0.0, 0.0)
) -> np.ndarray:
    """[4,4] T_base_headcam of the sample's fixed head camera (OpenCV axes).

    Over the robot's left shoulder, 0.95 m above the table, looking down at the workspace centre: it
    sees the table in front of the robot, the objects there, and a board held up in front of it. A
    camera straight behind the base (y = 0) looks through the Panda's upper arm in its home pose.
    """
    return look_at_pose(eye, target)


def _rigid(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def board_face(mesh: trimesh.Trimesh, face_normal_obj: np.ndarray = (0.0, 0.0, 1.0)) -> tuple[np.ndarray, np.ndarray]:
    """Printed face of a board mesh: its outer rectangle and in-plane axes, in the board's object frame.

    ``face_normal_obj`` is the outward normal of the printed face and must be an object-frame axis
    (+-x, +-y, +-z); the face is the mesh's bounding box side on that axis.

    Returns ``corners [4,3]`` (counter-clockwise seen from the front, starting at the (a_min, b_min)
    corner) and ``axes [3,3]`` whose columns are (a, b, n): a = the longer in-plane axis, b = n x a,
    n = the face normal, so (a, b, n) is right-handed.
    """
    n = np.asarray(face_normal_obj, dtype=np.float64)
    n = n / np.linalg.norm(n)
    k = int(np.argmax(np.abs(n)))
    if abs(abs(n[k]) - 1.0) > 1e-9:
        raise ValueError(f"board face normal must be an object-frame axis, got {face_normal_obj}")
    lo, hi = np.asarray(mesh.bounds, dtype=np.float64)
    i, j = (ax for ax in range(3) if ax != k)
    ia = i if hi[i] - lo[i] >= hi[j] - lo[j] else j
    a = np.eye(3)[ia]
    b = np.cross(n, a)
    centre = 0.5 * (lo + hi)
    centre[k] = hi[k] if n[k] > 0 else lo[k]
    ha = 0.5 * (hi - lo) @ np.abs(a)
    hb = 0.5 * (hi - lo) @ np.abs(b)
    corners = np.stack([centre + sa * ha * a + sb * hb * b for sa, sb in ((-1, -1), (1, -1), (1, 1), (-1, 1))])
    return corners, np.stack([a, b, n], axis=1)


def _face_normal_obj(board: PlacedAsset) -> np.ndarray:
    return np.asarray(board.meta.get("face_normal_obj", (0.0, 0.0, 1.0)), dtype=np.float64)


def default_T_hand_board(board: PlacedAsset, robot: RobotSpec = ROBOT) -> np.ndarray:
    """[4,4] fixed mount of a board in the robot's end-effector link frame: gripped by one long edge.

    In the tool frame (``robot.T_ee_tcp``: z along the approach, the fingers closing along y) the board
    stands in the x-z plane, centred between the fingers: its longer in-plane axis a along x, its printed
    face looking along +y, its near edge ``BOARD_GRIP_EDGE_DEPTH`` behind the tool centre so the fingertip
    pads pinch its margin, the rest of it beyond the fingers. Board axes (a, b, n) -> tool (x, -z, y).
    """
    _, axes = board_face(board.mesh, _face_normal_obj(board))
    lo, hi = np.asarray(board.mesh.bounds, dtype=np.float64)
    b = axes[:, 1]
    R_tcp_board = np.stack([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]], axis=1) @ axes.T
    centre_obj = 0.5 * (lo + hi)  # mid-thickness, so the fingers grip it symmetrically
    extent_b = float(np.abs(b) @ (hi - lo))
    mount_tcp = np.array([0.0, 0.0, -BOARD_GRIP_EDGE_DEPTH + 0.5 * extent_b])
    return robot.T_ee_tcp @ _rigid(R_tcp_board, mount_tcp - R_tcp_board @ centre_obj)


def _board_thickness(board: PlacedAsset) -> float:
    lo, hi = np.asarray(board.mesh.bounds, dtype=np.float64)
    return float(np.abs(_face_normal_obj(board)) @ (hi - lo))


# ---- the renderer ------------------------------------------------------------------------------
def _slug(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name) or "asset"


class SampleRenderer:
    """One Genesis scene of placed assets (optionally the robot holding a board) and one camera.

    assets        static / object meshes, placed at their ``T_base_obj`` (Genesis world = robot base)
    config        camera and lights
    with_robot    add the robot, base at the origin
    robot         which (a registered name, a robot spec file or a spec; default the Franka Panda)
    held_board    a board (category "board") mounted in the gripper at ``T_hand_board``; needs the robot.
                  Its printed face normal in its object frame is ``meta["face_normal_obj"]`` (default +z).
                  An asset of the same name in ``assets`` (the board lying on the table) is left out.
    T_hand_board  [4,4] mount of the board in the end-effector link's frame (default: :func:`default_T_hand_board`)
    workdir       where the OBJ exports go

    Building the scene takes ~35-60 s (kernel caches in ~/.cache make it faster); use it as a
    context manager, or call :meth:`close`.
    """

    def __init__(
        self,
        assets: list[PlacedAsset],
        config: RenderConfig | None = None,
        with_robot: bool = False,
        held_board: PlacedAsset | None = None,
        *,
        workdir: Path,
        T_hand_board: np.ndarray | None = None,
        robot: str | RobotSpec = DEFAULT_ROBOT,
    ) -> None:
        if held_board is not None and not with_robot:
            raise ValueError("held_board needs with_robot=True")
        self.spec = spec = get_robot(robot)
        self.robot_name = str(robot) if not isinstance(robot, RobotSpec) else robot.name
        self.config = config or RenderConfig()
        cfg = self.config
        workdir = Path(workdir)

        self._scene = RenderScene(cfg)
        self.entity_names = self._scene.names  # segmentation label i <-> entity_names[i]

        def add_asset(asset: PlacedAsset, index: int) -> object:
            folder = workdir / f"{index:03d}_{_slug(asset.name)}"
            return self._scene.add_mesh(asset.name, asset.mesh, asset.T_base_obj, folder)

        if held_board is not None:  # one board, in the gripper
            assets = [a for a in assets if a.name != held_board.name]
        for i, asset in enumerate(assets):
            add_asset(asset, i)

        self.robot = None
        self.board = held_board
        self._board_entity = None
        self.T_hand_board: np.ndarray | None = None
        if with_robot:
            self.robot = self._scene.add_robot(spec)
        if held_board is not None:
            self._board_entity = add_asset(held_board, len(assets))
            self.T_hand_board = np.asarray(
                default_T_hand_board(held_board, spec) if T_hand_board is None else T_hand_board, dtype=np.float64
            )
            self.board_corners_obj, self.board_axes_obj = board_face(held_board.mesh, _face_normal_obj(held_board))
            # Fingers just touching the board (visual only: the board does not collide).
            span = sorted((spec.gripper_closed, spec.gripper_open))
            self.finger_q = float(np.clip(0.5 * _board_thickness(held_board) - _PAD_INSET, *span))
        else:
            self.board_corners_obj = self.board_axes_obj = None
            self.finger_q = spec.gripper_open

        self._scene.add_camera("camera", cfg.width, cfg.height, cfg.focal)
        self._scene.build()
        if self.robot is not None:
            self.set_joints(spec.home)

    # ---- lifecycle -------------------------------------------------------------------------------
    def close(self) -> None:
        """Free the Genesis scene (GL context, solver). The renderer is unusable afterwards."""
        if self._scene is not None:
            self._scene.destroy()
            self._scene = None

    def __enter__(self) -> SampleRenderer:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    # ---- camera ----------------------------------------------------------------------------------
    @property
    def K(self) -> np.ndarray:
        """[3,3] intrinsics of every render (pixel centres at +0.5)."""
        return self.config.K

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return self.config.width, self.config.height

    def _render(self, T_world_cam: np.ndarray, **what: bool) -> tuple:
        T_world_cam = np.asarray(T_world_cam, dtype=np.float64)
        if T_world_cam.shape != (4, 4):
            raise ValueError(f"T_world_cam must be [4,4], got {T_world_cam.shape}")
        return self._scene.render("camera", T_world_cam, **what)

    def render(self, T_world_cam: np.ndarray) -> np.ndarray:
        """RGB image uint8 [H,W,3] seen by a camera with pose ``T_world_cam`` [4,4] (OpenCV axes)."""
        rgb, *_ = self._render(T_world_cam, rgb=True)
        return np.array(rgb, dtype=np.uint8, copy=True)

    def render_rgbd(self, T_world_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """RGB uint8 [H,W,3] and planar depth float32 [H,W] (metres along z; inf where nothing is hit)."""
        rgb, depth, *_ = self._render(T_world_cam, rgb=True, depth=True)
        return np.array(rgb, dtype=np.uint8, copy=True), self._clean_depth(depth)

    def render_depth(self, T_world_cam: np.ndarray) -> np.ndarray:
        """Planar depth float32 [H,W] in metres (camera z); inf where no geometry is hit."""
        _, depth, *_ = self._render(T_world_cam, rgb=False, depth=True)
        return self._clean_depth(depth)

    def _clean_depth(self, depth: np.ndarray) -> np.ndarray:
        depth = np.array(depth, dtype=np.float32, copy=True)
        # The cleared depth buffer linearises to ~far; 24-bit quantisation is metres there: call it "nothing".
        depth[depth >= 0.5 * self.config.far] = np.inf
        return depth

    def render_segmentation(self, T_world_cam: np.ndarray) -> np.ndarray:
        """Entity labels int32 [H,W]: i -> ``entity_names[i]``, -1 where nothing is hit."""
        _, _, seg, _ = self._render(T_world_cam, rgb=False, segmentation=True)
        return self._scene.labels(seg)

    def render_mask(self, T_world_cam: np.ndarray, name: str) -> np.ndarray:
        """bool [H,W]: pixels where entity ``name`` (an asset's name, "robot") is the visible surface."""
        return self.render_segmentation(T_world_cam) == self.entity_names.index(name)

    def place_asset(self, name: str, T_base_obj: np.ndarray) -> None:
        """Move the placed asset ``name`` to ``T_base_obj`` [4,4] (a link of the filmed robot's look, when the robot
        moves while filmed)."""
        pos, quat = pos_quat(T_base_obj)
        entity = self._scene.entities[name]
        entity.set_pos(pos)
        entity.set_quat(quat)

    # ---- robot -----------------------------------------------------------------------------------
    @property
    def robot_file(self) -> str:
        """The robot's model file (relative to Genesis' bundled assets, or absolute)."""
        return self.spec.model

    @property
    def ee_link(self) -> str:
        """The link holding the board (the hand)."""
        return self.spec.ee_link

    def _need_robot(self) -> object:
        if self.robot is None:
            raise RuntimeError("this renderer was built without the robot")
        return self.robot

    @property
    def joint_limits(self) -> tuple[np.ndarray, np.ndarray]:
        """(lower [n_dofs], upper [n_dofs]) joint limits: the arm joints (rad) then the finger joints."""
        lo, hi = self._need_robot().get_dofs_limit()
        return np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)

    def set_joints(self, q: np.ndarray) -> None:
        """Set the arm [n_arm] (fingers then grip the board, or open) or arm + fingers [n_dofs]; re-place the
        board."""
        robot, spec = self._need_robot(), self.spec
        q = np.asarray(q, dtype=np.float64).reshape(-1)
        if q.shape == (spec.n_arm,):
            q = np.concatenate([q, [self.finger_q] * (spec.n_dofs - spec.n_arm)])
        if q.shape != (spec.n_dofs,):
            raise ValueError(f"q must have {spec.n_arm} or {spec.n_dofs} values, got {q.shape}")
        robot.set_qpos(q)
        if self._board_entity is not None:
            pos, quat = pos_quat(self.T_base_board)
            self._board_entity.set_pos(pos)
            self._board_entity.set_quat(quat)

    def get_joints(self) -> np.ndarray:
        """Current joint positions [n_dofs] (arm then fingers)."""
        return np.asarray(self._need_robot().get_qpos(), dtype=np.float64)

    def T_base_link(self, name: str | None = None) -> np.ndarray:
        """[4,4] pose of a robot link (default: the end-effector link) from Genesis FK."""
        link = self._need_robot().get_link(self.spec.ee_link if name is None else name)
        return pose_from(link.get_pos(), link.get_quat())

    @property
    def T_base_board(self) -> np.ndarray:
        """[4,4] current pose of the held board's object frame: T_base_hand @ T_hand_board."""
        if self.T_hand_board is None:
            raise RuntimeError("this renderer holds no board")
        return self.T_base_link() @ self.T_hand_board

    def board_corners_base(self) -> np.ndarray:
        """[4,3] corners of the held board's printed face in the base frame (see :func:`board_face`)."""
        T = self.T_base_board
        return self.board_corners_obj @ T[:3, :3].T + T[:3, 3]

    def self_collision(self) -> bool:
        """Whether the arm's collision geometry intersects itself in the current joint state (the fingers closed on
        each other do not count: that is where they are on a thin board)."""
        robot = self._need_robot()
        link_of = {g.idx: g.link.name for g in robot.geoms}
        fingers = set(self.spec.finger_links)
        pairs = np.asarray(robot.detect_collision()).reshape(-1, 2)
        return any(not (link_of.get(int(i)) in fingers and link_of.get(int(j)) in fingers) for i, j in pairs)

    def board_intersects_arm(self, clearance: float = 0.01) -> bool:
        """Whether an arm link (any but the fingers holding it) reaches into the held
        board: the board does not collide in Genesis, so this is checked on the links' collision
        vertices, in the board's face frame. A link counts when its vertices over the face rectangle
        (grown by ``clearance``) come within ``clearance`` of the slab or lie on both sides of it.
        """
        robot = self._need_robot()
        T = self.T_base_board
        corners = self.board_corners_obj
        a, b, n = self.board_axes_obj.T
        centre = corners.mean(axis=0)
        half_a = 0.5 * np.ptp(corners @ a)
        half_b = 0.5 * np.ptp(corners @ b)
        thickness = _board_thickness(self.board)
        for link in robot.links:
            if link.name in self.spec.finger_links or link.n_verts == 0:
                continue
            X = np.asarray(link.get_verts(), dtype=np.float64)
            X_obj = (X - T[:3, 3]) @ T[:3, :3] - centre  # base -> board object frame, face centre origin
            over = (np.abs(X_obj @ a) <= half_a + clearance) & (np.abs(X_obj @ b) <= half_b + clearance)
            if not over.any():
                continue
            h = X_obj[over] @ n  # height over the printed face; the slab is [-thickness, 0]
            if h.min() < clearance and h.max() > -thickness - clearance:
                return True
        return False


# ---- hand-eye configurations --------------------------------------------------------------------
def _project(K: np.ndarray, T_world_cam: np.ndarray, X_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels [N,2] and camera depths [N] of world points [N,3]."""
    V = invert_rigid(T_world_cam)
    Xc = X_world @ V[:3, :3].T + V[:3, 3]
    uvw = Xc @ K.T
    return uvw[:, :2] / uvw[:, 2:3], Xc[:, 2]


def _polygon_mask(uv: np.ndarray, width: int, height: int) -> np.ndarray:
    """bool [H,W]: pixel centres inside the convex polygon uv [N,2] (vertices in order)."""
    u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    n = len(uv)
    sides = []
    for i in range(n):
        p, q = uv[i], uv[(i + 1) % n]
        sides.append((q[0] - p[0]) * (v - p[1]) - (q[1] - p[1]) * (u - p[0]))
    sides = np.stack(sides)
    return np.all(sides >= 0, axis=0) | np.all(sides <= 0, axis=0)


def _rotation_axes_spread_deg(Rs: list[np.ndarray]) -> float:
    """Largest angle (deg, 0..90) between the rotation axes of relative motions R_i^T R_j (i < j)."""
    axes = []
    for i in range(len(Rs)):
        for j in range(i + 1, len(Rs)):
            R = Rs[i].T @ Rs[j]
            w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
            if np.linalg.norm(w) > 1e-6:
                axes.append(w / np.linalg.norm(w))
    if len(axes) < 2:
        return 0.0
    A = np.stack(axes)
    cos = np.clip(np.abs(A @ A.T), 0.0, 1.0)
    return float(np.degrees(np.arccos(cos.min())))


@dataclass
class HandeyeCheck:
    """Why a configuration was accepted or not (for diagnostics and tests)."""

    ok: bool
    reason: str = ""
    facing_deg: float = float("nan")
    visible_fraction: float = float("nan")


def check_handeye_configuration(
    renderer: SampleRenderer,
    T_base_headcam: np.ndarray,
    *,
    margin_px: float = 20.0,
    max_facing_deg: float = 60.0,
    min_visible: float = 0.9,
    min_height: float = 0.03,
    render_check: bool = True,
) -> HandeyeCheck:
    """Check the renderer's current joint state for a hand-eye image from the head camera.

    In view: all printed-face corners project inside the image with ``margin_px`` and in front of
    the camera. Facing: face normal within ``max_facing_deg`` of the direction to the camera. No
    self-collision, no arm link through the board; board and hand above the table
    (z >= ``min_height``). With ``render_check``,
    at least ``min_visible`` of the projected face is the board's own surface in a segmentation
    render (not hidden by the arm).
    """
    W, H = renderer.size
    K = renderer.K
    lo, hi = renderer.joint_limits
    q = renderer.get_joints()
    if np.any(q < lo - 1e-6) or np.any(q > hi + 1e-6):
        return HandeyeCheck(False, "joint limits")
    corners = renderer.board_corners_base()
    uv, z = _project(K, T_base_headcam, corners)
    if np.any(z <= renderer.config.near):
        return HandeyeCheck(False, "behind camera")
    if np.any(uv < margin_px) or np.any(uv[:, 0] > W - margin_px) or np.any(uv[:, 1] > H - margin_px):
        return HandeyeCheck(False, "out of view")
    T_base_board = renderer.T_base_board
    n_base = T_base_board[:3, :3] @ renderer.board_axes_obj[:, 2]
    to_cam = T_base_headcam[:3, 3] - corners.mean(axis=0)
    facing = float(np.degrees(np.arccos(np.clip(n_base @ to_cam / np.linalg.norm(to_cam), -1.0, 1.0))))
    if facing > max_facing_deg:
        return HandeyeCheck(False, "not facing", facing)
    if corners[:, 2].min() < min_height or renderer.T_base_link()[2, 3] < min_height:
        return HandeyeCheck(False, "below table", facing)
    if renderer.self_collision():
        return HandeyeCheck(False, "self collision", facing)
    if renderer.board_intersects_arm():
        return HandeyeCheck(False, "board in arm", facing)
    visible = float("nan")
    if render_check:
        poly = _polygon_mask(uv, W, H)
        mask = renderer.render_mask(T_base_headcam, renderer.board.name)
        visible = float((mask & poly).sum() / max(poly.sum(), 1))
        if visible < min_visible:
            return HandeyeCheck(False, "occluded", facing, visible)
    return HandeyeCheck(True, "", facing, visible)


def sample_handeye_configurations(
    n: int,
    seed: int,
    T_base_headcam: np.ndarray,
    renderer: SampleRenderer,
    *,
    depth_range: tuple[float, float] | None = None,
    image_fill: tuple[float, float] = (0.4, 0.8),
    tilt_deg: tuple[float, float] = (5.0, 35.0),
    roll_deg: float = 90.0,
    min_separation_deg: float = 10.0,
    max_attempts: int = 2000,
    **check_kwargs: float,
) -> list[np.ndarray]:
    """``n`` joint configurations [n_dofs] of the robot for hand-eye images from the fixed head camera.

    Each draws a board pose in front of the camera: centre on a random ray through the middle
    half of the image at ``depth_range`` metres from the camera (default: where the board's diagonal
    spans ``image_fill`` of the image's smaller side), printed face towards the camera tilted by
    ``tilt_deg`` about a random in-plane axis and rolled up to +-``roll_deg`` about its normal.
    Inverse kinematics of the hand (``T_base_board @ inv(T_hand_board)``) from the home pose gives
    the joints; :func:`check_handeye_configuration` accepts or rejects them, and a board orientation
    closer than ``min_separation_deg`` to an accepted one is skipped. The random tilt axes make the
    relative motions rotate about non-parallel axes (Tsai-Lenz needs that); this is checked.

    Deterministic for a given seed. Leaves the renderer at the last configuration tried.
    """
    if renderer.board is None or renderer.robot is None:
        raise ValueError("the renderer must hold a board")
    rng = np.random.default_rng(seed)
    W, H = renderer.size
    K_inv = np.linalg.inv(renderer.K)
    T_base_headcam = np.asarray(T_base_headcam, dtype=np.float64)
    cam_centre = T_base_headcam[:3, 3]
    spec = renderer.spec
    hand = renderer.robot.get_link(spec.ee_link)
    T_board_hand = invert_rigid(renderer.T_hand_board)
    axes_obj = renderer.board_axes_obj
    # Face centre -> object-frame origin, to place the face centre on the sampled ray.
    face_centre_obj = renderer.board_corners_obj.mean(axis=0)
    q_home = spec.home_q(renderer.finger_q)
    if depth_range is None:
        diagonal = float(np.linalg.norm(renderer.board_corners_obj[2] - renderer.board_corners_obj[0]))
        span = renderer.K[1, 1] * diagonal / min(W, H)  # depth at which the diagonal fills the image
        depth_range = (span / image_fill[1], span / image_fill[0])
    accepted: list[np.ndarray] = []
    R_accepted: list[np.ndarray] = []
    for _ in range(max_attempts):
        if len(accepted) >= n and _rotation_axes_spread_deg(R_accepted) > 30.0:
            break
        u = rng.uniform(0.25 * W, 0.75 * W)
        v = rng.uniform(0.25 * H, 0.75 * H)
        ray = T_base_headcam[:3, :3] @ (K_inv @ np.array([u, v, 1.0]))
        p_base = cam_centre + rng.uniform(*depth_range) * ray
        n_des = (cam_centre - p_base) / np.linalg.norm(cam_centre - p_base)
        # Tilt about a random axis perpendicular to the normal, then roll about the tilted normal.
        perp = np.cross(n_des, rng.standard_normal(3))
        n_des = axis_angle_to_matrix(perp, math.radians(rng.uniform(*tilt_deg))) @ n_des
        up = np.array([0.0, 0.0, 1.0]) - n_des[2] * n_des  # board "b" axis nominally up in the image
        b_des = axis_angle_to_matrix(n_des, math.radians(rng.uniform(-roll_deg, roll_deg))) @ (up / np.linalg.norm(up))
        a_des = np.cross(b_des, n_des)
        R_base_board = np.stack([a_des, b_des, n_des], axis=1) @ axes_obj.T
        if any(rotation_angle(R.T @ R_base_board) < math.radians(min_separation_deg) for R in R_accepted):
            continue
        T_base_board = _rigid(R_base_board, p_base - R_base_board @ face_centre_obj)
        pos, quat = pos_quat(T_base_board @ T_board_hand)
        q = renderer.robot.inverse_kinematics(
            link=hand, pos=pos, quat=quat, init_qpos=q_home, max_samples=10, seed=int(rng.integers(2**31))
        )
        q = np.asarray(q, dtype=np.float64)
        q[spec.n_arm :] = renderer.finger_q
        renderer.set_joints(q)
        T_err = invert_rigid(renderer.T_base_link()) @ (T_base_board @ T_board_hand)
        if np.linalg.norm(T_err[:3, 3]) > 2e-3 or rotation_angle(T_err[:3, :3]) > math.radians(1.0):
            continue
        if not check_handeye_configuration(renderer, T_base_headcam, **check_kwargs).ok:
            continue
        accepted.append(q)
        R_accepted.append(renderer.T_base_board[:3, :3])
    if len(accepted) < n:
        raise RuntimeError(f"found only {len(accepted)} of {n} hand-eye configurations in {max_attempts} attempts")
    return accepted

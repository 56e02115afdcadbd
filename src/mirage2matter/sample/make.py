"""`m2m sample make`: the bundled sample capture with ground truth, rendered with Genesis.

Writes, into a new directory (built under a temporary name and renamed at the end, so a sample is
never half-written):

    scene.mp4            hand-held orbit around the table, H.264 (the robot at its base, in its own look, only with
                         ``robot_in_view``; at another pose from each frame of ``capture_moves`` on); through a
                         phone-like lens with ``lens`` (distortion, off-centre principal point), else the renderer's
                         pinhole
    head_view.png        the fixed head camera's view of the same scene (the robot in it as in the video, at
                         ``capture_joints``)
    handeye/images/*.png the head camera's view of a ChArUco board held by the robot's gripper
    handeye/joints.json  the joint angles of each hand-eye image
    handeye/board.json   the held board's spec
    gt/*.obj             ground-truth meshes (with .mtl and texture .png) of the board and objects
    board.json           the ChArUco board spec
    ground_truth.json    intrinsics, every frame's pose, board/object poses, T_base_headcam, extent
    contact_sheet.jpg    a few video frames and hand-eye images, for a person to look at
"""

from __future__ import annotations

import json
import os
import shutil
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from ..atomic import atomic_dir
from ..calib.board import BoardSpec, GridSpec, MarkerSpec
from ..errors import M2MError
from ..inputs import read_yaml
from ..render.lens import lens_rays, pinhole_cover, resample_through_lens
from ..robots import DEFAULT_ROBOT, get_robot
from ..robots.surface import check_capture_joints, robot_surface
from ..video import write_video
from ..world.sample_assets import LAYOUTS
from .inspect import BUNDLED_SAMPLE
from .lens import LENSES, LensConfig
from .trajectory import OrbitConfig, orbit_poses

GROUND_TRUTH_VERSION = 1


@dataclass(frozen=True)
class SampleConfig:
    seed: int = 0
    width: int = 640
    height: int = 480
    fov_deg: float = 50.0  # vertical field of view of a phone's main camera (and of the head camera)
    # The board lies where the robot base will stand. At 640x480 a 5x7 board of 4 cm squares is
    # too small to detect beyond ~1 m at the orbit's grazing angles; 7 cm squares with 4x4-bit
    # markers (bigger cells) and a higher, closer orbit put it in every sampled frame (probe: 30/30).
    # Any calibration target (calib.board): the ChArUco board by default; see `with_marker` for the others.
    board: Any = field(default_factory=lambda: BoardSpec(square=0.07, marker=0.055, dictionary="DICT_4X4_50"))
    # The board the robot holds for hand-eye calibration: smaller, so the arm can show it at many poses.
    handeye_board: BoardSpec = field(default_factory=lambda: BoardSpec(square=0.06, marker=0.045))
    orbit: OrbitConfig = field(
        default_factory=lambda: OrbitConfig(target=(0.2, 0.0, 0.0), radius=(0.75, 1.1), height=(0.5, 0.85))
    )
    handeye_views: int = 18
    crf: int = 23  # H.264 quality: visually clean at a few MB for the shipped sample
    # The robot holding the board in the hand-eye images (a registered name or a robot spec file); its base
    # stands at the origin like the default Panda's.
    robot: str = DEFAULT_ROBOT
    # The video camera's lens (sample.lens.LENSES): None films the video with the renderer's pinhole (fov_deg, the
    # head camera's); a lens renders a wider pinhole of the same focal length and resamples it through the lens
    # (ground_truth.json "camera" holds its K and distortion). The head camera stays the pinhole.
    lens: LensConfig | None = None
    # Where the objects stand (world.sample_assets.LAYOUTS): "nominal" (the shipped places, jittered for seeds != 0)
    # or "random" (drawn anywhere in the workspace for the seed)
    layout: str = "nominal"
    # The robot in the video (`with_robot_in_view`): it stands at its base at ``capture_joints`` (arm joints, rad;
    # None: world.sample_robot_look.capture_joints_for) with a look of its own (world.sample_robot_look), and the
    # board lies beside the base at ``board_at`` (x, y, yaw deg) instead of where the base stands
    robot_in_view: bool = False
    capture_joints: tuple[float, ...] | None = None
    board_at: tuple[float, float, float] | None = None
    # The robot's moves while filmed (with ``robot_in_view``): {video frame N: arm joints}, from frame N on it stands
    # there (an instant change, as if the user paused the recording, moved the arm and resumed); ``capture_joints``
    # holds before the first move. None: it stands still (`with_robot_in_view(second_pose=True)` moves it once).
    capture_moves: dict[int, tuple[float, ...]] | None = None

    @classmethod
    def short(cls, seed: int = 0) -> SampleConfig:
        """A quick version for tests: a few seconds of video at a low frame rate, fewer hand-eye views."""
        full = cls(seed=seed)
        return replace(full, orbit=replace(full.orbit, duration_s=4.0, fps=5.0), handeye_views=6)


MARKERS = {  # the table target of `with_marker`: the sizes labs tape down
    "charuco": None,
    "aruco": lambda: MarkerSpec(0.18, 0, "DICT_6X6_250", "aruco"),
    "apriltag": lambda: MarkerSpec(0.18, 0, "DICT_APRILTAG_36h11", "apriltag"),
    "aruco_grid": lambda: GridSpec(4, 5, 0.06, 0.015, "DICT_4X4_50"),
}


def with_lens(config: SampleConfig, lens: str) -> SampleConfig:
    """``config`` with the video filmed through the lens ``lens`` (a name in sample.lens.LENSES)."""
    if lens not in LENSES:
        raise SampleError(f"lens must be one of {', '.join(LENSES)}, got {lens!r}")
    return replace(config, lens=LENSES[lens])


def with_layout(config: SampleConfig, layout: str) -> SampleConfig:
    """``config`` with the objects placed by ``layout`` (one of world.sample_assets.LAYOUTS)."""
    if layout not in LAYOUTS:
        raise SampleError(f"layout must be one of {', '.join(LAYOUTS)}, got {layout!r}")
    return replace(config, layout=layout)


# The board beside the base when the robot stands in the video: 5.5 cm squares (the 7 cm board does not fit beside
# the base on the table), right of the base (-y), long side along x, clear of the objects, where the head camera sees
# it too (left of the base, at (-0.08, 0.32), the head camera saw two rows of it and its view check had no corners).
ROBOT_IN_VIEW_BOARD = BoardSpec(square=0.055, marker=0.042, dictionary="DICT_4X4_50")
ROBOT_IN_VIEW_BOARD_AT = (0.17, -0.3, 90.0)


def with_robot_in_view(
    config: SampleConfig, capture_joints: tuple[float, ...] | None = None, second_pose: bool = False
) -> SampleConfig:
    """``config`` filming the robot at its base (at ``capture_joints``, default the sample's pose), the board
    beside it; with ``second_pose`` the robot moves, at the video's middle frame, to the robot's second pose
    (world.sample_robot_look.second_pose_for), so that the orbit sees what the first pose hid. Choose the robot and
    the orbit first: the move is for ``config.robot`` at ``config.orbit``'s middle frame."""
    board = ROBOT_IN_VIEW_BOARD if isinstance(config.board, BoardSpec) and config.board.kind == "charuco" else \
        config.board  # fmt: skip
    moves = None
    if second_pose:
        from ..world.sample_robot_look import second_pose_for

        moves = {config.orbit.n_frames // 2: tuple(float(v) for v in second_pose_for(get_robot(config.robot)))}
    return replace(config, robot_in_view=True, capture_joints=capture_joints, board=board,
                   board_at=ROBOT_IN_VIEW_BOARD_AT, capture_moves=moves)  # fmt: skip


def with_marker(config: SampleConfig, marker: str) -> SampleConfig:
    """``config`` with the table's ChArUco board replaced by another kind of target (see MARKERS)."""
    if marker not in MARKERS:
        raise SampleError(f"marker must be one of {', '.join(MARKERS)}, got {marker!r}")
    return config if MARKERS[marker] is None else replace(config, board=MARKERS[marker]())


class SampleError(M2MError, ValueError):
    """Bad output location or failed generation; the message says what to do."""


def _check_output_dir(out: Path) -> None:
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise SampleError(f"{out} already exists and is not an empty directory; choose a new path or remove it")
    parent = out.parent
    if not parent.is_dir():
        raise SampleError(f"parent directory {parent} does not exist; create it first (mkdir -p {parent})")
    if not os.access(parent, os.W_OK):
        raise SampleError(f"cannot write into {parent}; choose a writable location")


def _save_png(path: Path, image: np.ndarray) -> None:
    from PIL import Image

    Image.fromarray(image).save(path, optimize=False)


def _contact_sheet(path: Path, tiles: list[np.ndarray], columns: int = 4, width: int = 320) -> None:
    from PIL import Image

    h = int(round(tiles[0].shape[0] * width / tiles[0].shape[1]))
    rows = (len(tiles) + columns - 1) // columns
    sheet = Image.new("RGB", (columns * width, rows * h), (255, 255, 255))
    for i, tile in enumerate(tiles):
        sheet.paste(
            Image.fromarray(tile).resize((width, h), Image.Resampling.BILINEAR),
            ((i % columns) * width, (i // columns) * h),
        )
    sheet.save(path, quality=88)


def _robot_ref(robot: str, renderer: Any) -> str:
    """The joints file's robot: the default robot's bundled model file (as the shipped sample has it), else the robot
    itself (a name or a spec file: a composed model lives in a machine's cache)."""
    return renderer.robot_file if robot == DEFAULT_ROBOT else robot


def _write_settings(path: Path, config: SampleConfig, objects: list[str], capture_joints=None,
                    capture_moves: dict[int, Any] | None = None) -> None:  # fmt: skip
    """The sample's m2m.yaml: the bundled one; with another robot, lens or layout, changed where they matter: the robot
    named once, at the top (the pipeline's), no video intrinsics with a lens (SfM calibrates the camera
    itself, as on a phone video), the objects named nearest the base first (``objects``: the names in that order),
    the robot's moves while filmed (``capture_moves``: {frame: arm joints})."""
    bundled = config.robot == DEFAULT_ROBOT and config.lens is None and config.layout == "nominal"
    if bundled and config.robot_in_view and config.capture_joints is None and not capture_moves:
        shutil.copyfile(BUNDLED_SAMPLE / "m2m.yaml", path)
        return

    data = read_yaml(BUNDLED_SAMPLE / "m2m.yaml", "sample settings")
    notes = []
    if config.robot != DEFAULT_ROBOT:
        data = {"robot": config.robot, **data}  # the whole pipeline's robot, at the top (align, handeye, compose)
        notes.append(f"The sample's robot: {config.robot} (`m2m sample make --robot {config.robot}`).")
    if config.lens is not None:
        data.get("sfm", {}).pop("intrinsics", None)
        if not data.get("sfm", True):
            del data["sfm"]
        notes.append(f"The video's lens ({config.lens.name}) is not given: SfM calibrates the camera itself "
                     "(ground_truth.json holds the true one under \"camera\").")  # fmt: skip
    if config.robot_in_view:  # the bundled sample's header says so already
        joints = {"capture_joints": [round(float(v), 6) for v in capture_joints]}
        if capture_moves:
            joints["capture_moves"] = {int(n): [round(float(v), 6) for v in q]
                                       for n, q in sorted(capture_moves.items())}  # fmt: skip
            frames = ", ".join(map(str, sorted(capture_moves)))
            notes.append(f"The robot moves while filmed: from video frame {frames} on it stands at capture_moves "
                         "(`m2m sample make --one-pose` keeps it still).")  # fmt: skip
        # the pipeline's settings (the top of the file), after the board's
        data = {k: v for k, v in data.items() if k not in joints and k != "capture_moves"}
        at = list(data).index("board_pose") + 1
        data = dict([*list(data.items())[:at], *joints.items(), *list(data.items())[at:]])
    else:  # no robot in the video: neither its joint state nor its moves (a move says it was filmed)
        data.pop("capture_joints", None)
        data.pop("capture_moves", None)
        notes.append("The table is filmed without the robot (`m2m sample make --empty-table`): it appears only in "
                     "the hand-eye images; the board lies where its base would stand.")  # fmt: skip
    if config.layout != "nominal":
        data.setdefault("objects", {})["names"] = list(objects)
        notes.append(f"Objects placed by layout {config.layout!r}, named nearest the robot base first.")
    lines = (BUNDLED_SAMPLE / "m2m.yaml").read_text().splitlines()
    robot_note, moves_note = "# The robot stands in the video", "# The robot moves while filmed"
    head = "".join(line + "\n" for line in lines if line.startswith("#") and not line.startswith(moves_note)
                   and (config.robot_in_view or not line.startswith(robot_note)))  # fmt: skip
    path.write_text(head + "".join(f"# {note}\n" for note in notes)
                    + yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=120))  # fmt: skip


def _config_json(config: SampleConfig) -> dict:
    """The config as ground_truth.json records it; a field added since the bundled sample is left out at its default,
    so a default sample's ground truth stays as it was."""
    out = asdict(config)
    if out["capture_moves"] is not None:  # JSON's keys are strings: the frame, as ground_truth.json's robot has it
        out["capture_moves"] = {str(n): list(q) for n, q in sorted(out["capture_moves"].items())}
    for key in ("lens", "layout", "robot_in_view", "capture_joints", "board_at", "capture_moves"):
        if out[key] == getattr(SampleConfig, key):
            del out[key]
    return out


def _nearest_first(assets: list) -> list[str]:
    """The objects' names (the button as "button") in order of distance from the robot base."""
    objects = {("button" if a.name == "button_base" else a.name): a.T_base_obj for a in assets
               if a.category == "object" or a.name == "button_base"}  # fmt: skip
    return sorted(objects, key=lambda name: float(np.hypot(*np.asarray(objects[name])[:2, 3])))


def _checked_moves(config: SampleConfig, spec: Any) -> dict[int, np.ndarray]:
    """The robot's moves while filmed: {video frame: joints [n_dofs]}, in frame order, each checked (a frame after
    the first and inside the video, joints within the robot's limits)."""
    n_frames = config.orbit.n_frames
    out = {}
    for n, q in sorted((config.capture_moves or {}).items()):
        if not 1 <= int(n) < n_frames:
            raise SampleError(f"capture_moves: frame {n} is not in the video after its first frame (1..{n_frames - 1})")
        out[int(n)] = check_capture_joints(spec, q, f"sample capture_moves[{n}]")
    return out


def make_sample(out: str | Path, config: SampleConfig = SampleConfig(), log: Callable[[str], None] = print) -> dict:
    """Generate the sample into the new directory ``out``; returns the ground truth dict."""
    out = Path(out)
    _check_output_dir(out)  # before the slow imports, so a bad path fails at once

    from ..world.sample_assets import board_asset, build_assets, export_assets, ground_truth_entries
    from ..world.sample_robot_look import ROBOT_LOOK_PREFIX, capture_joints_for, robot_look_assets
    from .render import RenderConfig, SampleRenderer, default_T_base_headcam, sample_handeye_configurations

    t_start = time.perf_counter()
    with atomic_dir(out) as tmp:  # an existing out is empty (checked above)
        (tmp / "handeye" / "images").mkdir(parents=True)
        board = config.board
        assets = build_assets(seed=config.seed, board=board, layout=config.layout, board_at=config.board_at)
        board.save(tmp / "board.json")
        config.handeye_board.save(tmp / "handeye" / "board.json")
        robot_assets, q_capture, moves = [], None, {}
        if config.robot_in_view:  # the robot at its base, static while filmed (but for its moves), in its own look
            spec = get_robot(config.robot)
            q_capture = check_capture_joints(spec, config.capture_joints if config.capture_joints is not None
                                             else capture_joints_for(spec), "sample capture_joints")  # fmt: skip
            robot_assets = robot_look_assets(spec, q_capture, config.seed)
            log(f"robot: {config.robot} in the video at {np.round(q_capture[: spec.n_arm], 3).tolist()}")
            moves = _checked_moves(config, spec)
            for n, q in moves.items():
                log(f"robot: from video frame {n} on at {np.round(q[: spec.n_arm], 3).tolist()}")
        elif config.capture_moves:
            raise SampleError("capture_moves needs the robot in the video (with_robot_in_view)")
        # the pipeline settings of the sample layout (inputs by relative path), as `m2m demo --sample` reads them
        n_arm = get_robot(config.robot).n_arm
        _write_settings(tmp / "m2m.yaml", config, _nearest_first(assets),
                        None if q_capture is None else q_capture[:n_arm],
                        {n: q[:n_arm] for n, q in moves.items()})  # fmt: skip
        ground_truth_assets = [a for a in assets if a.category in ("board", "object", "button")]
        mesh_paths = export_assets(ground_truth_assets, tmp / "gt")
        log(f"assets: {len(assets)} meshes, ground truth for {', '.join(mesh_paths)}")

        render_cfg = RenderConfig(width=config.width, height=config.height, fov_deg=config.fov_deg)
        times, poses = orbit_poses(config.orbit, seed=config.seed)
        T_base_headcam = default_T_base_headcam()
        K_head = render_cfg.K  # the head camera: the renderer's pinhole
        video_cfg, lens_camera, rays, crop = render_cfg, None, None, (0, 0)
        if config.lens is not None:  # a wider pinhole of the same focal length, resampled through the lens
            lens_camera = config.lens.camera(config.width, config.height)
            rays = lens_rays(lens_camera)
            width, height = pinhole_cover(rays, render_cfg.focal, (config.width, config.height))
            video_cfg = replace(render_cfg, width=width, height=height, fy=render_cfg.focal)
            crop = ((width - config.width) // 2, (height - config.height) // 2)  # the head camera's window of it
        tiles: list[np.ndarray] = []
        with SampleRenderer(assets + robot_assets, video_cfg, workdir=tmp / ".render") as renderer:
            K = renderer.K if lens_camera is None else lens_camera.K

            def place_robot(q: np.ndarray) -> None:
                for link in robot_surface(spec, q):
                    renderer.place_asset(f"{ROBOT_LOOK_PREFIX}{link.link}", link.T_base_link)

            def frames():
                pick = set(np.linspace(0, len(poses) - 1, 8).round().astype(int).tolist())
                for i, T in enumerate(poses):
                    if i in moves:  # the recording paused while the arm moved
                        place_robot(moves[i])
                    image = renderer.render(T)
                    if rays is not None:
                        image = resample_through_lens(image, video_cfg.focal, rays)
                    if i in pick:
                        tiles.append(image)
                    if i % 100 == 0:
                        log(f"video: frame {i + 1}/{len(poses)}")
                    yield image

            n = write_video(tmp / "scene.mp4", frames(), fps=config.orbit.fps, crf=config.crf)
            lens_note = "" if lens_camera is None else f" through the {config.lens.name} lens"
            log(f"video: {n} frames at {config.width}x{config.height}, {config.orbit.fps:g} fps{lens_note}")
            (x0, y0) = crop
            if moves:  # the head photo shows the robot at capture_joints, as the pipeline's head view expects
                place_robot(q_capture)
            head_view = renderer.render(T_base_headcam)[y0 : y0 + config.height, x0 : x0 + config.width]
            _save_png(tmp / "head_view.png", np.ascontiguousarray(head_view))

        table_board = next(a for a in assets if a.category == "board")
        held_board = board_asset(config.handeye_board)  # same name: it replaces the table board
        with SampleRenderer(
            assets,
            render_cfg,
            with_robot=True,
            held_board=held_board,
            workdir=tmp / ".render_robot",
            robot=config.robot,
        ) as robot_renderer:
            try:
                configurations = sample_handeye_configurations(
                    config.handeye_views, config.seed, T_base_headcam, robot_renderer
                )
            except RuntimeError as exc:
                raise SampleError(f"hand-eye poses: {exc}; use a smaller hand-eye board or fewer views") from None
            records = []
            for i, q in enumerate(configurations):
                robot_renderer.set_joints(q)
                image = robot_renderer.render(T_base_headcam)
                name = f"{i:04d}.png"
                _save_png(tmp / "handeye" / "images" / name, image)
                if i < 4:
                    tiles.append(image)
                records.append(
                    {
                        "image": f"images/{name}",
                        "joints": [float(v) for v in q],
                        "T_base_hand": robot_renderer.T_base_link().tolist(),
                    }
                )
            # the renderer mounts the slab's object frame; the ground truth is the ChArUco board frame
            T_hand_board = robot_renderer.T_hand_board @ np.asarray(held_board.meta["T_obj_board"])
        (tmp / "handeye" / "joints.json").write_text(
            json.dumps(
                {"robot": _robot_ref(config.robot, robot_renderer), "link": robot_renderer.ee_link, "views": records},
                indent=1,
            )
        )
        log(f"hand-eye: {len(records)} views of the held board from the head camera")

        verts = np.concatenate([(a.T_base_obj[:3, :3] @ a.mesh.vertices.T).T + a.T_base_obj[:3, 3] for a in assets])
        ground_truth = {
            "version": GROUND_TRUTH_VERSION,
            "seed": config.seed,
            "units": "metres, seconds",
            "frame": "robot base: z up, origin at the robot base; the table top is z = 0",
            "camera_convention": "OpenCV (x right, y down, z forward); K pixel centres at +0.5; T_a_b maps b to a",
            "camera": {
                "width": config.width,
                "height": config.height,
                "K": np.asarray(K).tolist(),
                "distortion": None if lens_camera is None else lens_camera.distortion_json(),
            },
            "video": {"file": "scene.mp4", "fps": config.orbit.fps, "n_frames": len(poses), "crf": config.crf},
            "frames": [
                {"index": i, "timestamp": float(t), "T_base_cam": T.tolist()}
                for i, (t, T) in enumerate(zip(times, poses, strict=True))
            ],
            "board": {
                "spec": board.to_json(),
                "T_base_board": np.asarray(table_board.meta["T_base_board"]).tolist(),
            },
            "objects": ground_truth_entries(ground_truth_assets, mesh_dir="gt"),
            "head_camera": {
                "T_base_headcam": np.asarray(T_base_headcam).tolist(),
                "K": np.asarray(K_head).tolist(),
                "width": config.width,
                "height": config.height,
                "image": "head_view.png",
            },
            "handeye": {
                "images": "handeye/images",
                "joints": "handeye/joints.json",
                "mount": "head (eye-to-hand)",
                "robot": config.robot,
                "T_hand_board": np.asarray(T_hand_board).tolist(),
                "board": config.handeye_board.to_json(),
            },
            "world_extent": {"min": verts.min(0).tolist(), "max": verts.max(0).tolist()},
            "config": _config_json(config),
        }
        if q_capture is not None:
            ground_truth["robot"] = {
                "name": config.robot, "in_view": True, "capture_joints": q_capture.tolist(),
                **({"capture_moves": {str(n): q.tolist() for n, q in moves.items()}} if moves else {}),
                # the name the bundled sample records (the look lives in world.sample_robot_look now); kept, so a
                # sample made again is the same bytes
                "look": "mirage2matter.sample.robot_look (the sample's seed)",
                "links": {a.meta["link"]: np.asarray(a.T_base_obj).tolist() for a in robot_assets},
            }  # fmt: skip
        (tmp / "ground_truth.json").write_text(json.dumps(ground_truth, indent=1))
        _contact_sheet(tmp / "contact_sheet.jpg", tiles)
        for scratch in (".render", ".render_robot"):
            shutil.rmtree(tmp / scratch, ignore_errors=True)
    log(f"sample written to {out} in {time.perf_counter() - t_start:.0f} s")
    return ground_truth

"""The workspace folder: every artifact path and the posed capture.

One class owns the layout (DESIGN.md section 3); the stages (``stages/``) are the only other code that
knows where things live in a workspace. Below them, libraries receive typed objects and folders.

    m2m.yaml  pipeline.json  run_summary.json (m2m run)  demo_summary.json (m2m demo)  report.html (every run)
    capture/   keyframes + keyframes.json
    sfm/       sfm.json + model/ (COLMAP)
    calib/     sim3_sfm_to_base.json, cameras_base.json, points_base.npy, colors_base.npy, overlay.png,
               handeye.json, head_view.png + head_view.json
    scene/     gaussians.ply, metrics.json, heldout.png (+ plan.json, checkpoint.pt while training)
    objects/   <name>/ (masks/, mesh.obj, collision/, gaussians.ply, align.json, figure.png), summary.json
    world/     world.yaml, world.ply, scene.ply, assets/, reconstruction.json, task_summary.json
    datasets/  <task>/ (a LeRobot dataset)
    policies/  <name>/ (policy.pt, checkpoint.pt, summary.json, loss_curve.png)
    evals/     <name>/ (summary.json, episodes.jsonl, rollout.mp4, contact_sheet.png)
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .errors import M2MError

if TYPE_CHECKING:  # geometry imports torch; `m2m --help` must not
    from .geometry.camera import Camera
    from .geometry.sim3 import Sim3

__all__ = ["PosedCapture", "Workspace", "WorkspaceError"]


class WorkspaceError(M2MError, RuntimeError):
    """A stage's input is missing from the workspace; the message names the stage to run."""


@dataclass
class PosedCapture:
    """Keyframe cameras and SfM points in one frame.

    cameras   sorted by name; ``name`` is the image path relative to ``image_dir``
    points    [M, 3] float64; colors [M, 3] uint8 RGB
    frame     "base" (metric, robot base) or "sfm" (arbitrary SfM frame and scale)
    """

    cameras: list[Camera]
    points: np.ndarray
    colors: np.ndarray
    image_dir: Path
    frame: str
    sim3_sfm_to_base: Sim3 | None = None


@dataclass(frozen=True)
class Workspace:
    """Paths of one workspace folder (nothing is created until a stage writes).

    Every path comes from :meth:`path`, so a staged view (:meth:`staged`) can send the artifacts a running
    stage writes into its staging folder while everything else still reads from the workspace.
    """

    root: Path

    def __init__(self, root: str | os.PathLike[str]) -> None:
        object.__setattr__(self, "root", Path(root))

    def path(self, *parts: str) -> Path:
        """``root / parts``: the one place workspace paths are made."""
        return self.root.joinpath(*parts)

    def staged(self, staging: Path, writes: Sequence[Path]) -> Workspace:
        """This workspace with the artifacts ``writes`` (paths relative to the root) and everything below them
        under ``staging`` instead: what a stage in a transaction writes into."""
        return _StagedWorkspace(self.root, Path(staging), tuple(Path(w) for w in writes))

    @property
    def committed(self) -> Workspace:
        """The workspace itself (a staged view's committed artifacts)."""
        return self

    # ---- top level --------------------------------------------------------------------------------
    @property
    def config_file(self) -> Path:
        return self.path("m2m.yaml")

    @property
    def record_file(self) -> Path:
        return self.path("pipeline.json")

    @property
    def run_summary(self) -> Path:
        return self.path("run_summary.json")

    @property
    def demo_summary(self) -> Path:
        return self.path("demo_summary.json")

    @property
    def report_html(self) -> Path:
        """the run report: the last run's stages, pictures, datasets, warnings and what to do next"""
        return self.path("report.html")

    @property
    def state_dir(self) -> Path:
        """hidden: the workspace lock and the staged outputs of running stages"""
        return self.path(".m2m")

    # ---- capture, sfm -----------------------------------------------------------------------------
    @property
    def capture_dir(self) -> Path:
        return self.path("capture")

    @property
    def keyframes_file(self) -> Path:
        return self.path("capture", "keyframes.json")

    @property
    def sfm_dir(self) -> Path:
        return self.path("sfm")

    @property
    def sfm_file(self) -> Path:
        return self.path("sfm", "sfm.json")

    @property
    def sfm_model(self) -> Path:
        return self.path("sfm", "model")

    # ---- calib ------------------------------------------------------------------------------------
    @property
    def calib_dir(self) -> Path:
        return self.path("calib")

    @property
    def alignment_file(self) -> Path:
        """sim3_sfm_to_base, the board and its pose, the fit's figures"""
        return self.path("calib", "sim3_sfm_to_base.json")

    @property
    def cameras_base_file(self) -> Path:
        return self.path("calib", "cameras_base.json")

    @property
    def points_base_file(self) -> Path:
        return self.path("calib", "points_base.npy")

    @property
    def colors_base_file(self) -> Path:
        return self.path("calib", "colors_base.npy")

    @property
    def overlay_png(self) -> Path:
        return self.path("calib", "overlay.png")

    @property
    def robot_capture_file(self) -> Path:
        """the robot as the capture saw it: capture joint state, whether the keyframes show it, its fit"""
        return self.path("calib", "robot.json")

    @property
    def robot_points_file(self) -> Path:
        """the SfM points on the robot (base frame), kept out of points_base.npy"""
        return self.path("calib", "robot_points_base.npy")

    @property
    def handeye_file(self) -> Path:
        return self.path("calib", "handeye.json")

    @property
    def head_view_png(self) -> Path:
        return self.path("calib", "head_view.png")

    @property
    def head_view_file(self) -> Path:
        return self.path("calib", "head_view.json")

    # ---- scene, objects ---------------------------------------------------------------------------
    @property
    def scene_dir(self) -> Path:
        return self.path("scene")

    @property
    def scene_ply(self) -> Path:
        return self.path("scene", "gaussians.ply")

    @property
    def robot_gaussians_dir(self) -> Path:
        """the robot as the capture saw it: <link>.ply (link frame) per link + robot.json"""
        return self.path("scene", "robot")

    @property
    def scene_metrics(self) -> Path:
        return self.path("scene", "metrics.json")

    @property
    def objects_dir(self) -> Path:
        return self.path("objects")

    @property
    def objects_summary(self) -> Path:
        return self.path("objects", "summary.json")

    # ---- world, datasets --------------------------------------------------------------------------
    @property
    def world_dir(self) -> Path:
        return self.path("world")

    @property
    def world_yaml(self) -> Path:
        return self.path("world", "world.yaml")

    @property
    def world_ply(self) -> Path:
        return self.path("world", "world.ply")

    @property
    def world_manifest(self) -> Path:
        """world.json: the index ranges of world.ply's parts"""
        return self.path("world", "world.json")

    def world_asset_dir(self, name: str) -> Path:
        """Assets the world owns (inserted objects, button parts, relit copies)."""
        return self.path("world", "assets", name)

    @property
    def task_summary(self) -> Path:
        return self.path("world", "task_summary.json")

    @property
    def datasets_dir(self) -> Path:
        return self.path("datasets")

    def object_dir(self, name: str) -> Path:
        return self.path("objects", name)

    def dataset_dir(self, slug: str) -> Path:
        return self.path("datasets", slug)

    # ---- policies, evaluations -----------------------------------------------------------------------
    @property
    def policies_dir(self) -> Path:
        return self.path("policies")

    def policy_dir(self, name: str) -> Path:
        return self.path("policies", name)

    @property
    def evals_dir(self) -> Path:
        return self.path("evals")

    def eval_dir(self, name: str) -> Path:
        return self.path("evals", name)

    # ---- reading ---------------------------------------------------------------------------------
    def require(self, path: Path, stage: str) -> Path:
        """``path``, or a WorkspaceError naming the command that writes it."""
        if not path.exists():
            raise WorkspaceError(f"{path} not found; run `m2m {stage} -w {self.root}` first")
        return path

    def board_on_table(self) -> tuple[dict, np.ndarray] | None:
        """(the calibration target's JSON, T_base_board [4,4]) as align-scene recorded them; None before align-scene
        or where it aligned without a target."""
        if not self.alignment_file.is_file():
            return None
        record = json.loads(self.alignment_file.read_text(encoding="utf-8"))
        if record.get("T_base_board") is None:
            return None
        return record.get("board") or {}, np.asarray(record["T_base_board"], np.float64)

    def target_on_table(self):
        """(the calibration target, as ``calib.board.target_from_json`` reads it; T_base_board [4,4]) as align-scene
        placed it; None without one."""
        from .calib.board import target_from_json

        board = self.board_on_table()
        return None if board is None or not board[0] else (target_from_json(board[0]), board[1])

    def board_plane(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(centre [3], up normal [3]) of the calibration target's face in the base frame (``calib.board.
        target_plane``): it lies on the table; None without one."""
        from .calib.board import target_plane

        board = self.target_on_table()
        return None if board is None else target_plane(*board)

    def posed_capture(self, frame: str = "auto") -> PosedCapture:
        """The keyframes' cameras and points. ``frame``: "base" (written by ``align-scene``; an error
        before it), "sfm" (the SfM model's own frame) or "auto" (base when aligned, else sfm)."""
        aligned = self.cameras_base_file.is_file() and self.points_base_file.is_file()
        if frame == "base" or (frame == "auto" and aligned):
            return self._posed_base()
        return self._posed_sfm()

    def _posed_sfm(self) -> PosedCapture:
        from .sfm import load_model_points, load_sfm_summary

        self.require(self.sfm_file, "sfm")
        _, cameras = load_sfm_summary(self.sfm_dir)
        points, colors = load_model_points(self.require(self.sfm_model, "sfm"))
        return PosedCapture(sorted(cameras, key=lambda c: c.name), points, colors, self.capture_dir, "sfm")

    def cameras_base(self) -> list:
        """The keyframes' cameras (``geometry.camera.Camera``) in the base frame, as align-scene wrote them, by name."""
        from .geometry.camera import Camera

        path = self.require(self.cameras_base_file, "align-scene")
        cameras = [Camera.from_json(c, source=str(path)) for c in json.loads(path.read_text())]
        return sorted(cameras, key=lambda c: c.name)

    def _posed_base(self) -> PosedCapture:
        from .geometry.sim3 import Sim3

        cameras = self.cameras_base()
        points = np.load(self.require(self.points_base_file, "align-scene")).astype(np.float64).reshape(-1, 3)
        if self.colors_base_file.is_file():
            colors = np.load(self.colors_base_file).astype(np.uint8).reshape(-1, 3)
        else:  # a workspace written before colours were kept, or by a test fixture
            colors = np.full((len(points), 3), 128, np.uint8)
        sim = None
        if self.alignment_file.is_file():
            sim = Sim3.from_json(json.loads(self.alignment_file.read_text())["sim3_sfm_to_base"])
        return PosedCapture(cameras, points, colors, self.capture_dir, "base", sim)


@dataclass(frozen=True)
class _StagedWorkspace(Workspace):
    """A workspace whose ``writes`` (relative paths) live under ``staging``; see :meth:`Workspace.staged`."""

    staging: Path
    writes: tuple[Path, ...]

    def __init__(self, root: Path, staging: Path, writes: tuple[Path, ...]) -> None:
        super().__init__(root)
        object.__setattr__(self, "staging", staging)
        object.__setattr__(self, "writes", writes)

    def path(self, *parts: str) -> Path:
        rel = Path(*parts)
        if any(rel == w or w in rel.parents for w in self.writes):
            return self.staging.joinpath(*parts)
        return self.root.joinpath(*parts)

    @property
    def committed(self) -> Workspace:
        return Workspace(self.root)

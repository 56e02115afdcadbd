"""The pipeline's stages, in order: the only code besides ``workspace.py`` that knows workspace paths.

:data:`STAGES` is the one list of them: each is a :class:`~.base.Stage` here and the module ``stages/<name>.py``
(``Config``, ``inputs``, ``outputs``, ``run``, optionally ``compare``) imported on first use; ``m2m <stage>``,
``m2m demo`` and ``m2m run`` all go through :func:`~.base.run_stage`. :class:`~.pipeline.PipelineConfig` (a
workspace's ``m2m.yaml``) is built from this list: one section per stage, holding its Config.
"""

from __future__ import annotations

from ..errors import M2MError
from .base import Input, Stage, run_stage

__all__ = ["PIPELINE", "STAGES", "Input", "Stage", "get_stage", "run_stage"]

STAGES: tuple[Stage, ...] = (
    Stage("capture", "capture", "pick keyframes (sharpness + parallax) from a video or an image folder"),
    Stage("sfm", "sfm", "camera poses and points of the keyframes (COLMAP SfM), or imported ones"),
    Stage("align", "align-scene", "the SfM scene in the robot-base frame, metric, via a calibration target"),
    Stage("handeye", "calibrate-handeye", "the camera's mount from board images + the robot's poses"),
    Stage("scene", "train-scene", "scene 3D Gaussian Splatting from the posed keyframes"),
    Stage("head_view", "head-view", "the scene through the calibrated head camera, against a head photo"),
    Stage("objects", "objects", "per object: masks, object 3DGS, watertight mesh + collision parts, aligned"),
    Stage("world", "compose", "the world (robot, cameras, scene, objects) and its one Gaussian world.ply"),
    Stage("generate", "generate", "demonstrations of tasks in the world -> LeRobot datasets"),
    Stage("train_policy", "train-policy", "a visuomotor policy trained on the workspace's datasets", pipeline=False),
    Stage(
        "eval_policy",
        "eval-policy",
        "a policy run closed-loop in the twin: success rate, video, report",
        pipeline=False,
    ),  # fmt: skip
)
# The stages a pipeline run (``m2m demo``, ``m2m run``) goes through, in order.
PIPELINE: tuple[Stage, ...] = tuple(s for s in STAGES if s.pipeline)


def get_stage(name: str) -> Stage:
    """The stage of that name (pipeline.json / m2m.yaml key) or command (``train-scene``)."""
    for s in STAGES:
        if name in (s.name, s.command):
            return s
    raise M2MError(f"unknown stage {name!r}; stages: {', '.join(s.name for s in STAGES)}")

"""Episodes from the simulated world: Genesis twin + scripted task + hybrid frames.

Per attempt (all drawn from the attempt's seed and recorded): object start poses (``twin.reset``:
every object and the button are placed at random, so the ones the task does not touch are the
distractors), a small camera-mount jitter per camera, and a light / colour jitter of the splat
world. Then the task runs; at every control tick (10 Hz) each camera gets a hybrid frame: the splat
world with every part at its physics pose, the Genesis robot render over it, depth-aware
(render/composite.py). Failed attempts return no frames.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field, fields, is_dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..export.spec import DatasetSpec, EpisodeData
from ..render.composite import ColorJitter, composite, to_uint8
from ..render.splat_world import MovablePart, SplatRenderOptions, SplatWorld
from ..sim.tasks import Task
from ..world.config import WorldConfig
from .config import Randomization
from .robot_proxy import lowpoly_robot
from .runner import Attempt

CAMERAS = ("head", "wrist")


@dataclass(frozen=True, eq=False)
class SimSourceConfig:
    """What an episode is: the world, the task, the frames. Picklable (it travels to worker processes and Ray
    actors as it is: the world and the task are parsed once, in the parent).

    world          the loaded world (the worker copies it before changing anything)
    task           the task object (``sim.tasks.parse_task``)
    size           (width, height) of every camera's frames
    fps            control and video rate
    cameras        which world cameras become videos
    randomization  per-episode jitter
    """

    world: WorldConfig
    task: Task
    size: tuple[int, int] = (224, 224)
    fps: int = 10
    cameras: tuple[str, ...] = CAMERAS
    randomization: Randomization = field(default_factory=Randomization)
    # Measured on a wrist-camera episode of the reconstructed sample world at 224 px: SH band 1 instead of 3 is
    # 43.5 dB from the full render and poses a part 2.4x faster; dropping Gaussians below opacity 0.02 (most
    # of an object reconstruction's are fainter) is 40 dB from it and renders ~12% faster.
    splat: SplatRenderOptions = field(default_factory=lambda: SplatRenderOptions(sh_degree=1, min_opacity=0.02))
    depth_aware: bool = True
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    # Render speed (CPU): the robot drawn from a copy with visual meshes decimated to this many faces each
    # (None: the original meshes), and cameras on the hand reuse the robot layer while the fingers keep their
    # opening (the hand and fingers do not move in such a camera; only their shading would, slightly).
    robot_render_faces: int | None = 1500
    reuse_hand_camera_robot: bool = True

    def spec(self) -> DatasetSpec:
        """The dataset's spec: the frames, and the state / action names and type of the world's robot."""
        w, h = self.size
        robot = self.world.robot.spec
        return DatasetSpec(
            state_names=robot.state_names,
            action_names=robot.action_names,
            robot_type=robot.robot_type,
            fps=self.fps,
            cameras={c: (h, w) for c in self.cameras},
        )

    def to_json(self) -> dict[str, Any]:
        """The task and every frame setting, not the world (fingerprinted by its content, see ``generate``)."""
        out: dict[str, Any] = {"task": self.task.to_json()}
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name not in ("world", "task"):
                out[f.name] = asdict(v) if is_dataclass(v) else v
        return {**out, "size": list(self.size), "cameras": list(self.cameras)}


def render_K(K: np.ndarray, width: int, height: int, out_w: int, out_h: int) -> np.ndarray:
    """Intrinsics of the ``out_w`` x ``out_h`` render of a camera (the Genesis twin's convention: the
    vertical field of view kept, square pixels, principal point at the centre)."""
    f = float(K[1, 1]) * out_h / height
    return np.array([[f, 0.0, out_w / 2.0], [0.0, f, out_h / 2.0], [0.0, 0.0, 1.0]])


def _small_rotation(rng: np.random.Generator, max_deg: float) -> np.ndarray:
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    a = math.radians(rng.uniform(-max_deg, max_deg))
    Kx = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(a) * Kx + (1 - math.cos(a)) * Kx @ Kx


class SimEpisodeSource:
    """Builds the twin and the splat world once; :meth:`run` makes one attempt."""

    def __init__(self, cfg: SimSourceConfig):
        from ..gaussians.ply import read_ply
        from ..sim.twin import Twin, TwinOptions

        self.cfg = cfg
        self.spec = cfg.spec()
        t0 = time.perf_counter()
        world = cfg.world.copy()  # the render robot and the per-episode camera jitter change it
        missing = [c for c in cfg.cameras if c not in world.cameras]
        if missing:
            raise ValueError(f"the world has no calibrated camera {missing}; cameras: {sorted(world.cameras)} "
                             "(run `m2m calibrate-handeye` / `m2m compose` first)")  # fmt: skip
        self.task = cfg.task
        if cfg.robot_render_faces and world.robot.file.lower().endswith(".xml"):
            world.robot.file = str(lowpoly_robot(world.robot.file, robot_cache_dir(), cfg.robot_render_faces))
        w, h = cfg.size
        self.twin = Twin.build(world, TwinOptions(render=True, camera_sizes={c: (w, h) for c in cfg.cameras},
                                                  draw_scene=False))
        self.mounts = {c: world.cameras[c].T_mount_cam.copy() for c in cfg.cameras}
        self.static_cameras = {c for c in cfg.cameras if world.cameras[c].mount == "base"}
        self.hand_cameras = {c for c in cfg.cameras if world.cameras[c].mount == world.robot.ee_link}
        parts = [MovablePart(o.name, read_ply(o.part.gaussians), o.placement.scale) for o in world.objects]
        for a in world.articulated:
            parts.append(MovablePart(a.name, read_ply(a.base.gaussians), a.placement.scale))
            parts.append(MovablePart(f"{a.name}/cap", read_ply(a.cap.gaussians), a.placement.scale))
        static = read_ply(world.scene_gaussians) if world.scene_gaussians is not None else None
        self.splat = SplatWorld(static, parts, cfg.splat)
        self.build_s = time.perf_counter() - t0

    def _robot_layer(self, camera: str, w: int, h: int, state: np.ndarray) -> dict[str, np.ndarray]:
        if not (self.cfg.reuse_hand_camera_robot and camera in self.hand_cameras):
            return self.twin.render_robot(camera, w, h)
        key = tuple(np.round(np.asarray(state[7:9], np.float64) / 5e-4).astype(int))  # 0.5 mm finger steps
        hit = self._robot_cache.get(camera)
        if hit is None or hit[0] != key:
            hit = (key, self.twin.render_robot(camera, w, h))
            self._robot_cache[camera] = hit
        return hit[1]

    def run(self, attempt: int, seed: int) -> Attempt:
        from ..geometry.sim3 import invert_rigid
        from ..sim.tasks import run_task

        cfg, rnd, twin = self.cfg, self.cfg.randomization, self.twin
        rng = np.random.default_rng(seed)
        # Draw every random choice up front, in a fixed order, so the record fully describes the episode.
        jitter = ColorJitter.sample(rng, rnd.brightness, rnd.contrast, rnd.gain)
        mounts = {}
        for c in cfg.cameras:
            T = np.eye(4)
            T[:3, :3] = _small_rotation(rng, rnd.camera_deg) if rnd.camera_deg > 0 else np.eye(3)
            T[:3, 3] = rng.uniform(-rnd.camera_m, rnd.camera_m, 3) if rnd.camera_m > 0 else 0.0
            mounts[c] = self.mounts[c] @ T  # jitter in the camera's own frame
        reset_seed = int(rng.integers(2**31))
        task_rng = np.random.default_rng(rng.integers(2**31))

        timings = {"reset": 0.0, "splat_render": 0.0, "robot_render": 0.0, "composite": 0.0, "pose_splats": 0.0}
        t = time.perf_counter()
        for c in cfg.cameras:
            twin.cfg.cameras[c].T_mount_cam = mounts[c]
        start_poses = twin.reset(reset_seed, randomize=rnd.objects)
        self.splat.reset_cache()
        self._robot_cache: dict[str, tuple] = {}
        timings["reset"] = time.perf_counter() - t
        w, h = cfg.size
        frames: dict[str, list[np.ndarray]] = {c: [] for c in cfg.cameras}
        states, actions = [], []

        def on_step(rec) -> None:
            t0 = time.perf_counter()
            self.splat.set_poses(rec.object_poses)
            timings["pose_splats"] += time.perf_counter() - t0
            for c in cfg.cameras:
                T_base_cam, K, cw, ch = twin.camera(c)
                t1 = time.perf_counter()
                view, Kr = invert_rigid(T_base_cam), render_K(K, cw, ch, w, h)
                if c in self.static_cameras:  # fixed in the base: the scene is drawn once per episode
                    rgb, alpha, depth = self.splat.render_static_camera(c, view, Kr, w, h, cfg.background)
                else:
                    rgb, alpha, depth = self.splat.render_camera(c, view, Kr, w, h, cfg.background)
                t2 = time.perf_counter()
                robot = self._robot_layer(c, w, h, rec.state)
                t3 = time.perf_counter()
                splat8 = to_uint8(jitter.apply(rgb))
                if cfg.depth_aware:
                    im, _ = composite(splat8, robot["rgb"], robot["robot_mask"], robot["depth"], depth, alpha)
                else:
                    im, _ = composite(splat8, robot["rgb"], robot["robot_mask"])
                frames[c].append(im)
                timings["splat_render"] += t2 - t1
                timings["robot_render"] += t3 - t2
                timings["composite"] += time.perf_counter() - t3
            states.append(rec.state)
            actions.append(rec.action)

        t = time.perf_counter()
        result = run_task(twin, self.task, task_rng, on_step=on_step, control_hz=cfg.fps)
        total = time.perf_counter() - t
        render = sum(timings[k] for k in ("splat_render", "robot_render", "composite", "pose_splats"))
        timings["physics_and_planning"] = total - render
        record = {
            "reset_seed": reset_seed,
            "start_poses": {k: np.round(v, 6).tolist() for k, v in start_poses.items()},
            "camera_mounts": {c: np.round(m, 6).tolist() for c, m in mounts.items()},
            "color_jitter": jitter.to_json(),
            "task": self.task.to_json(),
            "task_info": {k: v for k, v in result.info.items() if isinstance(v, int | float | str | bool)},
            "steps": len(result.steps),
        }
        if not result.success:
            return Attempt(False, result.reason or "task failed", None, record, timings)
        episode = EpisodeData(
            task=self.task.instruction,
            images={c: np.stack(f) for c, f in frames.items()},
            state=np.stack(states).astype(np.float32),
            action=np.stack(actions).astype(np.float32),
        )
        return Attempt(True, "", episode, record, timings)


@dataclass(frozen=True)
class SimSourceFactory:
    """Picklable: builds a :class:`SimEpisodeSource` inside a worker."""

    cfg: SimSourceConfig

    def __call__(self) -> SimEpisodeSource:
        return SimEpisodeSource(self.cfg)


def robot_cache_dir() -> Path:
    import os

    return Path(os.environ.get("M2M_CACHE", Path.home() / ".cache" / "mirage2matter")) / "robots"

"""``TwinEnv``: a Gymnasium environment of a world's Genesis twin, observed like the datasets ``m2m generate``
writes, so a policy trained on one of them runs here with no adapter.

- **Observation** (a dict, the datasets' feature keys): ``observation.images.<camera>`` uint8 [H,W,3] per camera
  (``EpisodeSpec.cameras``, default head and wrist), ``observation.state`` float32 [n_dofs] (arm joints in rad,
  fingers in m: the robot spec's ``state_names``).
- **Action**: float32 [n_arm + 1] (arm joint targets in rad, gripper target in m per finger: the spec's
  ``action_names``), within the model's joint limits and the gripper's range (clipped there). One step is one
  control tick at ``fps`` through ``Twin.act``, the function the scripted expert of generation acts through.
- **Episode**: ``reset(seed=s)`` draws the episode's randomisation exactly as generation draws episode ``s``
  (``env.episode.draw_episode``: camera-mount and colour jitter, object start poses), so a generated episode's
  recorded actions stepped from ``reset(seed=its seed)`` reproduce it. ``terminated`` is the task's success test
  (``Task.monitor``, latched), reward 1 on success, ``truncated`` at ``horizon`` steps. ``info``: ``success``,
  ``reason``, ``step``, ``sim_s``; at the episode's end (terminated or truncated) also ``timings`` (seconds per
  part; wall-clock numbers only there, so two identical episodes give identical step infos).
"""

from __future__ import annotations

import inspect
import os
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces

from ..errors import EpisodeStalled
from ..sim.tasks import Task, parse_task, steps_per_tick
from ..world.config import WorldConfig
from .config import EnvConfig, EnvError, EpisodeSpec, HybridOptions, Randomization, check_config
from .episode import EpisodeDraw, draw_episode
from .renderers import build_renderer

__all__ = ["STATE_KEY", "TwinEnv", "image_key", "make_config", "resolve_world"]

STATE_KEY = "observation.state"


def image_key(camera: str) -> str:
    """The observation (and dataset feature) key of a camera's frames."""
    return f"observation.images.{camera}"


def resolve_world(world: WorldConfig | str | os.PathLike) -> WorldConfig:
    """A loaded world as it is, or a world folder / its world.yaml (a workspace's is ``<workspace>/world``), loaded
    once here."""
    from ..world import load_world
    from ..world.config import world_yaml_path

    if isinstance(world, WorldConfig):
        return world
    if not isinstance(world, str | os.PathLike):
        raise EnvError(f"world must be a loaded WorldConfig or a world folder, got {world!r}")
    p = Path(world)
    if world_yaml_path(p).is_file():
        return load_world(p)
    raise EnvError(f"{p}: no world.yaml there; pass a world folder (a workspace's: <workspace>/world, written by "
                   "`m2m compose` or `m2m run`)")  # fmt: skip


def make_config(
    world: WorldConfig | str | os.PathLike,
    task: Task | str,
    renderer: str = "hybrid",
    size: int | tuple[int, int] | None = None,
    fps: int | None = None,
    horizon: int | None = EnvConfig.horizon,
    cameras: tuple[str, ...] | list[str] | None = None,
    randomization: Randomization | None = None,
    hybrid: HybridOptions | None = None,
    ground_truth: str | os.PathLike | None = None,
    backend: str = "cpu",
    episode: EpisodeSpec | None = None,
) -> EnvConfig:
    """Parse the environment's arguments once, at the border (see :class:`TwinEnv`), and check them. The frames
    are ``episode``'s (None: :class:`EpisodeSpec`'s defaults) with ``size``, ``fps``, ``cameras`` given here."""
    world = resolve_world(world)
    if isinstance(task, str):
        task = parse_task(task, world)
    elif not isinstance(task, Task):
        raise EnvError(f"task must be an instruction such as 'grasp banana' or a parsed Task, got {task!r}")
    episode = episode if episode is not None else EpisodeSpec()
    if isinstance(size, int):
        size = (size, size)
    try:
        w, h = size if size is not None else episode.size
    except (TypeError, ValueError):
        raise EnvError(f"size must be an integer or (width, height), got {size!r}") from None
    episode = replace(episode, size=(w, h), fps=episode.fps if fps is None else fps,
                      cameras=episode.cameras if cameras is None else tuple(cameras))  # fmt: skip
    cfg = EnvConfig(
        world=world, task=task, renderer=renderer, episode=episode, horizon=horizon,
        randomization=randomization or Randomization(), hybrid=hybrid or HybridOptions(),
        ground_truth=Path(ground_truth) if ground_truth is not None else None, backend=backend,
    )  # fmt: skip
    check_config(cfg)
    return cfg


class TwinEnv(gymnasium.Env):
    """The twin of a world running one task (module docstring: observations, actions, episodes).

    ``TwinEnv(world, task, renderer="hybrid", size=None, fps=None, horizon=200, cameras=None,
    randomization=Randomization(), hybrid=HybridOptions(), ground_truth=None, backend="cpu", episode=None,
    render_mode=None)`` or ``gymnasium.make("mirage2matter/Twin-v0", ...)`` with the same arguments; ``world`` is a
    loaded ``WorldConfig`` or a world folder (a workspace's: ``<workspace>/world``), ``task`` an instruction or a
    parsed ``Task``;
    the frames are ``EpisodeSpec()``'s unless ``size`` (a side or (width, height)), ``fps``, ``cameras`` or a whole
    ``episode`` say otherwise.
    ``TwinEnv.from_config(cfg)`` takes an :class:`EnvConfig`. Building takes the twin's build (~15 s warm).
    ``render_mode="rgb_array"``: :meth:`render` gives the cameras' last frames side by side.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": EpisodeSpec.fps}  # an instance's: its config's fps

    def __init__(self, world: WorldConfig | str | os.PathLike, task: Task | str, render_mode: str | None = None,
                 **options: Any) -> None:  # fmt: skip
        known = set(inspect.signature(make_config).parameters) - {"world", "task"}
        unknown = sorted(set(options) - known)
        if unknown:
            raise EnvError(f"TwinEnv: unknown option(s) {unknown}; options: {sorted(known)}")
        self._setup(make_config(world, task, **options), render_mode)

    @classmethod
    def from_config(cls, cfg: EnvConfig, render_mode: str | None = None) -> TwinEnv:
        """The environment of an already parsed configuration (checked again here)."""
        check_config(cfg)
        self = cls.__new__(cls)
        self._setup(cfg, render_mode)
        return self

    def _setup(self, cfg: EnvConfig, render_mode: str | None) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise EnvError(f"render_mode must be None or one of {self.metadata['render_modes']}, got {render_mode!r}")
        self.config, self.task, self.render_mode = cfg, cfg.task, render_mode
        self.twin = None
        self.twin, self.renderer = build_renderer(cfg)
        twin = self.twin
        robot = twin.spec
        self.substeps = steps_per_tick(twin, cfg.fps)
        self.tick_s = self.substeps * twin.dt
        self.metadata = {**type(self).metadata, "render_fps": cfg.fps}
        self.instruction = cfg.task.instruction
        # the calibrated mounts, before any episode's jitter (the twin's world copy is jittered per episode)
        self._mounts = {c: twin.cfg.cameras[c].T_mount_cam.copy() for c in cfg.cameras}

        lo, hi = twin.action_limits
        self.action_space = spaces.Box(lo.astype(np.float32), hi.astype(np.float32), dtype=np.float32)
        qlo, qhi = (v[: robot.n_dofs] for v in twin.joint_limits)
        # Joint limits are soft in physics: an empty gripper squeezed shut reads ~-4 mm at first (of a 4 cm range).
        pad = 0.25 * (qhi - qlo)
        w, h = cfg.size
        obs = {image_key(c): spaces.Box(0, 255, (h, w, 3), dtype=np.uint8) for c in cfg.cameras}
        obs[STATE_KEY] = spaces.Box((qlo - pad).astype(np.float32), (qhi + pad).astype(np.float32), dtype=np.float32)
        self.observation_space = spaces.Dict(obs)
        self.action_names, self.state_names = robot.action_names, robot.state_names

        self.draw: EpisodeDraw | None = None
        self.start_poses: dict[str, np.ndarray] = {}
        self.timings: dict[str, float] = {}
        self._monitor = None
        self._obs: dict[str, np.ndarray] | None = None
        self._t = 0

    # ---- the Gymnasium API ---------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[dict[str, np.ndarray], dict]:
        """Episode ``seed`` (None: one drawn from the environment's generator): its randomisation, the twin's
        reset, the first observation; ``info``: ``seed`` (the episode's), ``task`` (its language instruction)."""
        super().reset(seed=seed)
        if options:
            raise EnvError(f"reset options are not supported, got {sorted(options)}")
        twin, cfg = self._twin(), self.config
        episode_seed = int(seed) if seed is not None else int(self.np_random.integers(2**31))
        t0 = time.perf_counter()
        self.draw = draw = draw_episode(episode_seed, cfg.randomization, cfg.cameras)
        for c in cfg.cameras:
            twin.cfg.cameras[c].T_mount_cam = self._mounts[c] @ draw.T_cam_camj[c]
        self.start_poses = twin.reset(
            draw.reset_seed, randomize=cfg.randomization.objects, regions=cfg.randomization.regions()
        )
        self.renderer.start_episode(draw)
        self._monitor = self.task.monitor(twin, self.tick_s)
        self._t = 0
        self.timings = {"reset": time.perf_counter() - t0, "physics": 0.0}
        obs = self._observe()
        return obs, {"seed": episode_seed, "task": self.instruction}

    def step(self, action: np.ndarray) -> tuple[dict[str, np.ndarray], float, bool, bool, dict]:
        """One control tick from ``action`` (float32 [n_arm + 1]), then the observation and the success test."""
        twin = self._twin()
        if self._monitor is None:
            raise EnvError("call reset() before step()")
        a = self._action(action)
        t0 = time.perf_counter()
        twin.act(a.astype(np.float64), self.substeps)
        self.timings["physics"] += time.perf_counter() - t0
        self._t += 1
        success = self._monitor.update(twin)
        obs = self._observe()
        terminated = bool(success)
        truncated = not terminated and self.config.horizon is not None and self._t >= self.config.horizon
        info = {
            "success": terminated,
            "reason": self._monitor.reason,
            "step": self._t,
            "sim_s": round(self._t * self.tick_s, 9),
        }
        if terminated or truncated:
            info["timings"] = dict(self.timings)
        return obs, float(terminated), terminated, truncated, info

    def render(self) -> np.ndarray | None:
        """``rgb_array``: the cameras' last frames side by side (uint8 [H, W * cameras, 3])."""
        if self.render_mode != "rgb_array" or self._obs is None:
            return None
        return np.concatenate([self._obs[image_key(c)] for c in self.config.cameras], axis=1)

    def close(self) -> None:
        """Free the renderer and the Genesis scene (again: nothing)."""
        if getattr(self, "twin", None) is not None:
            try:
                self.renderer.close()
            finally:
                self.twin.close()
                self.twin = None

    def set_task(self, task: Task | str) -> None:
        """Run ``task`` from the next ``reset`` on, in the same world, cameras and frames: the built twin and renderer
        are kept (building them is most of an environment's start-up; a reset restores everything an episode
        changed, so an episode does not depend on the tasks run before it)."""
        if isinstance(task, str):
            task = parse_task(task, self.config.world)
        elif not isinstance(task, Task):
            raise EnvError(f"task must be an instruction such as 'grasp banana' or a parsed Task, got {task!r}")
        task.check(self.config.world)
        self.config = replace(self.config, task=task)
        self.task, self.instruction = task, task.instruction
        self._monitor, self._obs = None, None  # step() needs a reset under the new task

    # ---- helpers -------------------------------------------------------------------------------------
    @property
    def success(self) -> bool:
        """Whether the current episode has succeeded (the task's test, latched)."""
        return bool(self._monitor is not None and self._monitor.success)

    @property
    def steps(self) -> int:
        """Steps taken in the current episode."""
        return self._t

    def _twin(self):
        if self.twin is None:
            raise EnvError("the environment is closed; make a new one")
        return self.twin

    def _action(self, action: Any) -> np.ndarray:
        n = len(self.action_names)
        try:
            a = np.asarray(action, dtype=np.float32)
        except (TypeError, ValueError):
            raise EnvError(f"an action is float32 [{n}] ({', '.join(self.action_names)}), got {action!r}") from None
        if a.shape != (n,):
            raise EnvError(
                f"an action is float32 [{n}] ({', '.join(self.action_names)}) for robot {self.twin.spec.name!r}, "
                f"got shape {a.shape}"
            )
        if not np.isfinite(a).all():
            raise EnvError(f"action {a.tolist()} holds NaN or infinity")
        return a

    def _observe(self) -> dict[str, np.ndarray]:
        try:
            frames = self.renderer.render()
        except EpisodeStalled:
            self._monitor = None  # this episode is over: step() needs a reset
            raise
        finally:
            for k, v in self.renderer.timings.items():
                self.timings[k] = v
        obs = {image_key(c): np.array(frames[c], dtype=np.uint8, copy=True) for c in self.config.cameras}
        obs[STATE_KEY] = self.twin.robot_state().astype(np.float32)
        self._obs = obs
        return {k: v.copy() for k, v in obs.items()}

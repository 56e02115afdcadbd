"""Episodes from the simulated world: the twin environment (``env.TwinEnv``) with the scripted expert acting.

An attempt is an environment episode: ``env.reset(seed=attempt's seed)`` draws the episode's randomisation
(object start poses - every object and the button are placed at random, so the ones the task does not touch
are the distractors -, a small camera-mount jitter per camera, a light / colour jitter of the splat world), then
the task's script runs tick by tick at ``fps``, each tick's action going through ``env.step`` (so through
``Twin.act`` and the env's hybrid renderer: the splat world with every part at its physics pose, the Genesis
robot composited over it, depth-aware). The episode records, per tick, the frames and state the env observed
before the tick and the tick's action. Failed attempts return no frames.

With a takeover (``SimSourceConfig.takeover``), a trained policy acts first, through the same ``env.step``, for a
number of ticks drawn from the episode's seed; the expert's script then runs from that state and the episode is
recorded from there (the policy's ticks are not recorded: their actions are not the expert's).
"""

from __future__ import annotations

import hashlib
import json
import time
from dataclasses import asdict, dataclass, field, fields, is_dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from ..env.config import GROUND_TRUTH_TEXTURE_FILTER, EnvConfig, EpisodeSpec, HybridOptions, Randomization
from ..export.spec import DatasetSpec, EpisodeData
from ..ray_cluster import splat_resources
from ..sim.tasks import Task
from ..world.config import WorldConfig
from .config import Takeover
from .shipping import ShippedFactory, pack, world_files
from .worker import Attempt

__all__ = ["SimEpisodeSource", "SimSourceConfig", "SimSourceFactory"]

TAKEOVER_STREAM = 0x7A4E  # the takeover step's own random stream of an episode seed (no other draw moves)


@dataclass(frozen=True, eq=False)
class SimSourceConfig:
    """What an episode is: the world, the task, the frames. Picklable (it travels to worker processes and Ray
    actors as it is: the world and the task are parsed once, in the parent).

    world          the loaded world (the environment copies it before changing anything)
    task           the task object (``sim.tasks.parse_task``)
    episode        the frames (size, cameras) and their rate: generation's section (``GenerateConfig.episode``)
    randomization  per-episode jitter
    hybrid         the hybrid renderer's settings (splat quality, depth-aware compositing, render speed)
    takeover       None, or a trained policy that acts first in every episode (:class:`~.config.Takeover`)
    ground_truth   None: hybrid frames; a sample folder (with ground_truth.json): the frames are drawn by that sample's
                   ground-truth renderer instead (``env.ground_truth``; the world must be the one reconstructed from
                   it): demonstrations in the pictures of the sim-to-real bench's "real world", its oracle
    """

    world: WorldConfig
    task: Task
    episode: EpisodeSpec = field(default_factory=EpisodeSpec)
    randomization: Randomization = field(default_factory=Randomization)
    hybrid: HybridOptions = field(default_factory=HybridOptions)
    takeover: Takeover | None = None
    ground_truth: Path | None = None

    def spec(self) -> DatasetSpec:
        """The dataset's spec: the frames, and the state / action names and type of the world's robot."""
        w, h = self.episode.size
        robot = self.world.robot.spec
        return DatasetSpec(
            state_names=robot.state_names,
            action_names=robot.action_names,
            robot_type=robot.robot_type,
            fps=self.episode.fps,
            cameras={c: (h, w) for c in self.episode.cameras},
        )

    def env_config(self) -> EnvConfig:
        """The environment the episodes run in (hybrid frames, or the sample's ground truth's; no horizon: the
        script ends an episode)."""
        renderer = "hybrid" if self.ground_truth is None else "ground_truth"
        return EnvConfig(world=self.world, task=self.task, renderer=renderer, episode=self.episode, horizon=None,
                         randomization=self.randomization, hybrid=self.hybrid,
                         ground_truth=self.ground_truth)  # fmt: skip

    def to_json(self) -> dict[str, Any]:
        """The task and every frame setting, not the world (fingerprinted by its content, see ``generate``). The
        episode's settings stand at the top level, as before they were a section: a dataset's fingerprint is
        unchanged."""
        e = self.episode
        out: dict[str, Any] = {"task": self.task.to_json(), "size": list(e.size), "fps": e.fps,
                               "cameras": list(e.cameras)}  # fmt: skip
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name not in ("world", "task", "takeover", "episode", "ground_truth"):
                out[f.name] = asdict(v) if is_dataclass(v) else v
        if self.takeover is not None:  # absent without one: datasets made before the option keep their fingerprint
            out["takeover"] = self.takeover.to_json()
        if self.ground_truth is not None:  # likewise; by content (a moved sample draws the same pictures)
            gt = Path(self.ground_truth) / "ground_truth.json"
            out["ground_truth"] = {"sha1": hashlib.sha1(gt.read_bytes()).hexdigest(),
                                   "texture_filter": GROUND_TRUTH_TEXTURE_FILTER}  # fmt: skip
        if out["hybrid"].get("objects") == "gaussians":  # the default: datasets made before the option keep their key
            del out["hybrid"]["objects"]
        if out["hybrid"]["splat"].get("supersample") == 1:  # likewise
            del out["hybrid"]["splat"]["supersample"]
        if out["hybrid"].get("robot_look") == "auto":  # likewise (a world without robot Gaussians draws the mesh)
            del out["hybrid"]["robot_look"]
        for key in ("object_shrink", "table_texture", "start_regions"):  # likewise
            if not out["randomization"].get(key):
                del out["randomization"][key]
        return out


class SimEpisodeSource:
    """Builds the environment (twin + hybrid renderer) once; :meth:`run` makes one attempt. ``splat_server``: a
    running splat server's handle, which then draws the splat layer (``env.hybrid.HybridRenderer``)."""

    def __init__(self, cfg: SimSourceConfig, splat_server: Any = None):
        from ..env.twin_env import TwinEnv

        self.cfg = cfg
        self.spec = cfg.spec()
        self.task = cfg.task
        self.splat_server = splat_server
        t0 = time.perf_counter()
        self.env = TwinEnv.from_config(replace(cfg.env_config(), splat_server=splat_server))
        self.twin = self.env.twin
        # the policy of a takeover, on the CPU: a small network beside the worker's rendering, no GPU context per worker
        self.policy = cfg.takeover.open("cpu") if cfg.takeover is not None else None
        self.build_s = time.perf_counter() - t0

    def retarget(self, factory: Any) -> bool:
        """Serve ``factory``'s episodes (another dataset of a worker pool) with this environment when only the task
        differs - the same world, frames, randomisation, renderer settings and takeover: the task is swapped, nothing
        is rebuilt (an episode is a function of its seed and task alone: measured bit-identical frames, states and
        actions after other tasks' episodes). False: it cannot (build a new source)."""
        if not isinstance(factory, SimSourceFactory) or (factory.splat_server, self.splat_server) != (None, None):
            return False  # a splat server's handle belongs to one run
        if _without_task(factory.cfg) != _without_task(self.cfg):
            return False
        self.env.set_task(factory.cfg.task)
        self.cfg, self.task = factory.cfg, factory.cfg.task
        self.spec = factory.cfg.spec()
        return True

    def close(self) -> None:
        """Free the environment (Genesis scene, renderer)."""
        self.env.close()

    def _policy_first(self, obs: dict, seed: int) -> tuple[dict, int, float, str]:
        """The takeover's policy acts from the episode's first observation for its drawn number of ticks ->
        (the observation there, the ticks, their seconds, why the attempt ends here: "" to go on)."""
        lo, hi = self.cfg.takeover.steps
        n = int(np.random.default_rng([int(seed), TAKEOVER_STREAM]).integers(lo, hi + 1))
        t0 = time.perf_counter()
        self.policy.reset()
        for i in range(n):
            obs, _, terminated, _, _ = self.env.step(self.policy(obs))
            if terminated:  # the task is done: there is nothing for the expert to correct
                return obs, i + 1, time.perf_counter() - t0, (f"the policy succeeded on its own at step {i + 1}, "
                                                                f"before its takeover at step {n}")  # fmt: skip
        return obs, n, time.perf_counter() - t0, ""

    def run(self, attempt: int, seed: int) -> Attempt:
        from ..env.twin_env import STATE_KEY, image_key
        from ..sim.tasks import run_task

        cfg, env = self.cfg, self.env
        obs, _ = env.reset(seed=seed)
        parts = ("splat_render", "robot_render", "composite", "pose_splats")
        takeover: dict[str, Any] = {}
        policy_frames = dict.fromkeys(parts, 0.0)  # rendering time of the policy's ticks, per part
        if self.policy is not None:
            before = {k: env.timings.get(k, 0.0) for k in parts}
            obs, n_policy, policy_s, ended = self._policy_first(obs, seed)
            takeover = {"step": n_policy, "seconds": round(policy_s, 3)}
            policy_frames = {k: env.timings.get(k, 0.0) - before[k] for k in parts}
            if ended:
                record = {"reset_seed": env.draw.reset_seed, "takeover": takeover, "steps": 0}
                return Attempt(False, ended, None, record, {"takeover": policy_s})
        frames: dict[str, list[np.ndarray]] = {c: [obs[image_key(c)]] for c in cfg.episode.cameras}
        observed = [obs[STATE_KEY]]
        states, actions = [], []

        def act(action: np.ndarray) -> None:  # the expert's tick is an env step
            obs, *_ = env.step(action)
            for c in cfg.episode.cameras:
                frames[c].append(obs[image_key(c)])
            observed.append(obs[STATE_KEY])

        def on_step(rec) -> None:
            states.append(rec.state)
            actions.append(rec.action)

        rendered0 = sum(env.timings.get(k, 0.0) for k in parts)  # the first frame's, in the reset (and the policy's)
        t = time.perf_counter()
        result = run_task(self.twin, self.task, np.random.default_rng(env.draw.task_seed), on_step=on_step,
                          control_hz=cfg.episode.fps, act=act)  # fmt: skip
        total = time.perf_counter() - t
        n = len(actions)
        if n and not np.array_equal(np.stack(states), np.stack(observed[:n])):
            raise RuntimeError("generation recorded other states than the environment observed")  # a bug, not input
        timings = {k: float(env.timings.get(k, 0.0)) for k in ("reset", *parts)}
        timings["physics_and_planning"] = total - (sum(timings[k] for k in parts) - rendered0)
        if takeover:  # the policy's ticks (physics, rendering, network) apart: the parts are the reset's and expert's
            timings["takeover"] = takeover["seconds"]
            for k in parts:
                timings[k] -= policy_frames[k]
        record = {
            "reset_seed": env.draw.reset_seed,
            "start_poses": {k: np.round(v, 6).tolist() for k, v in env.start_poses.items()},
            "camera_mounts": {
                c: np.round(self.twin.cfg.cameras[c].T_mount_cam, 6).tolist() for c in cfg.episode.cameras
            },
            "color_jitter": env.draw.jitter.to_json(),
            **({"table_texture": env.draw.table_texture.to_json()} if env.draw.table_texture is not None else {}),
            "task": self.task.to_json(),
            "task_info": {k: v for k, v in result.info.items() if isinstance(v, int | float | str | bool)},
            "steps": n,
            **({"takeover": {**takeover, "state": np.round(observed[0], 6).tolist()}} if takeover else {}),
        }
        if not result.success:
            return Attempt(False, result.reason or "task failed", None, record, timings)
        episode = EpisodeData(
            task=self.task.instruction,
            images={c: np.stack(f[:n]) for c, f in frames.items()},  # the frame after the last action is not kept
            state=np.stack(states).astype(np.float32),
            action=np.stack(actions).astype(np.float32),
        )
        return Attempt(True, "", episode, record, timings)


def _without_task(cfg: SimSourceConfig) -> str:
    """Everything of a source's configuration but its task, comparable across processes (the world by content)."""
    rest = {k: v for k, v in cfg.to_json().items() if k != "task"}
    return json.dumps({"world": cfg.world.to_dict(), **rest}, sort_keys=True, default=str)


@dataclass(frozen=True)
class SimSourceFactory:
    """Picklable (a splat server's handle only into processes as they are spawned): builds a
    :class:`SimEpisodeSource` inside a worker."""

    cfg: SimSourceConfig
    splat_server: Any = None

    def __call__(self) -> SimEpisodeSource:
        return SimEpisodeSource(self.cfg, self.splat_server)

    @property
    def starts_children(self) -> bool:
        """Whether its source starts a process of its own (the ground-truth renderer draws in a child that a stall
        can be stopped in): its worker process must not be daemonic."""
        return self.cfg.ground_truth is not None

    def portable(self) -> Any:
        """This factory with the files its episodes read (the world's splats, meshes, collision parts, robot
        Gaussians and spec, a takeover's policies: those inside the world's workspace) as content, for workers on
        machines that do not see this one's disk (datagen/shipping.py)."""
        if self.splat_server is not None:
            raise RuntimeError("a splat server's handle serves local worker processes only")  # refused in _check
        return ShippedFactory(self, pack(_files(self.cfg), self.cfg.world.root.parent))

    def resources(self) -> Any:
        """What a Ray worker of this source asks for: a CPU for physics and encoding, and a share of a GPU when the
        splat renderer is told to use CUDA (its options, or ``M2M_RENDER_BACKEND=cuda`` on the driver, which the workers
        get too): Ray then places it on a GPU node; "auto" asks for none."""
        return splat_resources(self.cfg.hybrid.splat.backend)


def _files(cfg: SimSourceConfig) -> list[Path]:
    """Every file or folder an environment built from ``cfg`` opens, and a takeover's policies."""
    out = world_files(cfg.world)
    if cfg.takeover is not None:
        out += [Path(d) for d in cfg.takeover.policies]
    return out

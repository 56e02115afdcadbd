"""Generation from a simulated world: ``generate(world, task, out, cfg)``.

Takes typed objects (a loaded :class:`WorldConfig`, a parsed task); knows no workspace. Bad input is refused
here, in the parent, before any worker starts: a world without the cameras to record, a task whose target the
world lacks; ``generate_dataset`` refuses an output folder holding another dataset.
"""

from __future__ import annotations

import hashlib
import json
import re
from collections.abc import Callable
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..env.config import EnvError, HybridOptions, check_config
from ..env.hybrid import splat_parts
from ..env.lens import lens_plan
from ..env.robot_proxy import render_robot_file
from ..errors import M2MError
from ..render.splat_server import SplatServer
from ..robots import is_spec_file
from .config import GenerateConfig
from .dataset import GenerateError, generate_dataset, run_fingerprint
from .runner import WorkerPool

if TYPE_CHECKING:
    from ..sim.tasks import Task
    from ..world.config import WorldConfig

__all__ = [
    "dataset_fingerprint",
    "generate",
    "task_slug",
    "worker_pool",
    "world_fingerprint",
]

def task_slug(task: str) -> str:
    """A folder name for a task's dataset: "push croissant --distance 0.1" -> "push_croissant_distance_0_1"."""
    return re.sub(r"[^a-z0-9]+", "_", task.lower()).strip("_") or "dataset"


def world_fingerprint(world: WorldConfig) -> dict[str, Any]:
    """The world's content hash (world.yaml's fields, paths relative to its folder; a user's robot spec file by its
    content): a changed world is a different dataset."""
    text = json.dumps(world.to_dict(), sort_keys=True, default=str)
    out = {"world_sha1": hashlib.sha1(text.encode()).hexdigest()}
    if is_spec_file(world.robot.name):
        out["robot_sha1"] = hashlib.sha1(Path(world.robot.name).read_bytes()).hexdigest()
    return out


def _source(world: WorldConfig, task: Task, cfg: GenerateConfig):
    """What an episode of ``task`` is: generation's episode, randomisation, renderer and takeover sections."""
    from .sim_source import SimSourceConfig

    return SimSourceConfig(world=world, task=task, episode=cfg.episode, randomization=cfg.randomization,
                           hybrid=cfg.hybrid, takeover=cfg.takeover, ground_truth=cfg.ground_truth)  # fmt: skip


def _source_fingerprint(world: WorldConfig, source) -> dict[str, Any]:
    return {**world_fingerprint(world), "source": json.loads(json.dumps(source.to_json(), default=str))}


def dataset_fingerprint(world: WorldConfig, task: Task, cfg: GenerateConfig) -> dict[str, Any]:
    """The fingerprint summary.json records for this dataset (world content, task, frames, count, seed,
    format): a finished dataset holding it is the one ``generate`` would write."""
    return run_fingerprint(_source_fingerprint(world, _source(world, task, cfg)), cfg.run)


def _check(world: WorldConfig, task: Task, cfg: GenerateConfig) -> None:
    """Fail fast, in the parent, with the message a user can act on."""
    from ..sim.tasks import TaskError

    if cfg.splat_server and cfg.run.ray_address:
        raise GenerateError("--splat-server serves local worker processes; it cannot serve Ray actors (drop "
                            "--ray-address, or --splat-server)")  # fmt: skip
    if cfg.ground_truth is not None:
        _check_ground_truth(world, cfg)
    missing = [c for c in cfg.episode.cameras if c not in world.cameras]
    if missing:
        raise GenerateError(
            f"the world has no calibrated camera {', '.join(missing)} (cameras: {sorted(world.cameras) or 'none'}); "
            "calibrate it (`m2m calibrate-handeye`) and compose the world again"
        )
    try:
        task.check(world)
    except TaskError as e:
        raise GenerateError(f"task {task.text!r}: {e}") from None
    try:  # what the environment the episodes run in checks (frame size, fps against the physics rate)
        check_config(_source(world, task, cfg).env_config())
    except EnvError as e:
        raise GenerateError(str(e)) from None
    if cfg.takeover is not None:
        _check_takeover(world, cfg)


def _check_ground_truth(world: WorldConfig, cfg: GenerateConfig) -> None:
    """Frames drawn by a sample's ground truth: a readable sample, and no setting that only the hybrid renderer has
    (it would be silently ignored)."""
    from ..env.ground_truth import GroundTruthError, read_ground_truth

    try:  # a world not reconstructed from this sample fails as each worker builds its renderer (the objects' names)
        read_ground_truth(cfg.ground_truth)
    except GroundTruthError as e:
        raise GenerateError(f"generate --renderer ground_truth: {e}") from None
    if cfg.run.ray_address:
        raise GenerateError("generate --renderer ground_truth runs local workers (the sample's files are not shipped "
                            "to a Ray cluster); drop --ray-address")  # fmt: skip
    h, default = cfg.hybrid, HybridOptions()
    hybrid_only = [name for name, on in (
        ("--objects meshes", h.objects != default.objects), ("--supersample", h.splat.supersample != 1),
        ("--robot-look", h.robot_look != default.robot_look), ("--splat-server", cfg.splat_server),
        ("--table-texture", bool(cfg.randomization.table_texture)),
        ("--object-shrink", bool(cfg.randomization.object_shrink))) if on]  # fmt: skip
    if hybrid_only:
        raise GenerateError(f"generate --renderer ground_truth: {', '.join(hybrid_only)} set(s) how the hybrid "
                            "renderer draws; the ground-truth renderer draws the sample's own world (drop them)")


def _check_takeover(world: WorldConfig, cfg: GenerateConfig) -> None:
    """The takeover's policies open and were trained for this robot, rate and these cameras (the policy's error
    names the file), before any worker builds a twin."""
    problems = cfg.takeover.problems()
    if problems:
        raise GenerateError("generate: " + "; ".join(problems))
    spec = world.robot.spec
    try:
        policy = cfg.takeover.open("cpu")
        policy.check_matches(robot_type=spec.robot_type, state_names=spec.state_names, action_names=spec.action_names,
                             fps=cfg.episode.fps, cameras=cfg.episode.cameras)  # fmt: skip
    except M2MError as e:  # the policy package's errors (a damaged file, another robot's policy)
        raise GenerateError(f"generate --takeover: {e}") from None


def generate(
    world: WorldConfig,
    task: Task,
    out: Path,
    cfg: GenerateConfig,
    log: Callable[[str], None] = print,
    progress: bool = True,
    pool: WorkerPool | None = None,
) -> dict[str, Any]:
    """Generate ``cfg.run.episodes`` demonstrations of ``task`` in ``world`` into the dataset folder ``out``;
    returns the summary (summary.json) with ``"dataset"`` the dataset folder. A rerun of a finished run is a
    no-op; a killed run resumes (the fingerprint: world content, task, frame settings, seed, count, format).
    ``pool``: workers kept across tasks (:func:`worker_pool`): each worker's twin is built once and serves every
    task's episodes; not used with a splat server (its workers hold one run's server handle)."""
    from .sim_source import SimSourceFactory

    _check(world, task, cfg)
    out = Path(out)
    source = _source(world, task, cfg)
    run = cfg.run
    render_robot_file(world.robot.file, source.hybrid.robot_render_faces)  # built once, before workers race for it
    fingerprint, extra = _source_fingerprint(world, source), {"task": task.text, "dataset": str(out)}
    if not cfg.splat_server:
        return generate_dataset(out, SimSourceFactory(source), source.spec(), run, fingerprint, extra, log, progress,
                                pool)  # fmt: skip
    with _splat_server(world, source, cfg, log) as (handle, server):
        summary = generate_dataset(out, SimSourceFactory(source, handle), source.spec(), run, fingerprint, extra, log,
                                   progress)  # fmt: skip
        summary["splat_server"] = server.close()
    return summary


def worker_pool(cfg: GenerateConfig) -> WorkerPool:
    """Workers for several tasks' ``generate`` calls with ``cfg`` (a context manager; they start with the first
    attempt): the tasks then pay one twin build and warm-up instead of one each."""
    return WorkerPool(cfg.run.workers, cfg.run.ray_address)


@contextmanager
def _splat_server(world: WorldConfig, source, cfg: GenerateConfig, log: Callable[[str], None]):
    """A splat server for the run's workers: one slot per worker, the workers' splat settings and cameras."""

    workers = max(cfg.run.workers, 1)
    plan = lens_plan(source.env_config())  # cameras with a lens are drawn wider, then resampled (env.lens)
    size = plan.render_size if plan is not None else tuple(source.episode.size)
    server = SplatServer(splat_parts(world, objects=source.hybrid.objects == "gaussians",
                                     robot=source.hybrid.robot_gaussians(world)), source.hybrid.splat,
                         slots=workers, cameras=len(source.episode.cameras), size=size,
                         background=source.hybrid.background, table_z=world.table_z)  # fmt: skip
    handle = server.start()
    log(f"splat server: {server.stats['gaussians']:,} Gaussians, {workers} slot(s), pid {handle.pid}")
    try:
        yield handle, server
    finally:
        server.close()

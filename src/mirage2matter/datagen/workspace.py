"""Generation bound to a workspace: ``generate(ws, GenerateConfig)`` and ``bench_datagen``.

Bad input is refused before any worker starts: a missing or invalid world, a world without the
cameras to record, an unknown task or object, an output folder holding another dataset.
"""

from __future__ import annotations

import json
import re
import shutil
import statistics
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from .generate import GenerateError, RunConfig, generate_dataset
from .sim_source import Randomization, SimSourceConfig, SimSourceFactory, world_fingerprint


@dataclass(frozen=True)
class GenerateConfig:
    """``m2m generate``: what to generate and how (defaults: 224x224 head + wrist at 10 Hz, LeRobot v3.0)."""

    task: str
    episodes: int
    workers: int = 1
    ray_address: str | None = None
    format: str = "lerobot-v3.0"
    seed: int = 0
    out: Path | None = None  # default <ws>/datasets/<task slug>
    size: tuple[int, int] = (224, 224)
    fps: int = 10
    cameras: tuple[str, ...] = ("head", "wrist")
    max_attempts: int | None = None
    preview: int = 4
    randomization: Randomization = field(default_factory=Randomization)


def task_slug(task: str) -> str:
    return re.sub(r"[^a-z0-9]+", "_", task.lower()).strip("_") or "dataset"


def _check_world(ws: Path, cfg: GenerateConfig) -> None:
    """Fail fast, in the parent, with the message a user can act on."""
    from ..sim.tasks import TaskError, parse_task
    from ..world.config import WorldConfigError, load_world

    try:
        world = load_world(ws)
    except WorldConfigError as e:
        raise GenerateError(str(e)) from None
    missing = [c for c in cfg.cameras if c not in world.cameras]
    if missing:
        raise GenerateError(
            f"the world has no calibrated camera {', '.join(missing)} (cameras: {sorted(world.cameras) or 'none'}); "
            "calibrate it (`m2m calibrate-handeye`) and compose the world again"
        )
    try:
        parse_task(cfg.task, world)
    except TaskError as e:
        raise GenerateError(str(e)) from None


def generate(
    ws: str | Path, cfg: GenerateConfig, log: Callable[[str], None] = print, progress: bool = True
) -> dict[str, Any]:
    """Generate ``cfg.episodes`` demonstrations of ``cfg.task`` in the workspace's world; returns the summary
    (summary.json), with ``"dataset"`` the dataset folder."""
    ws = Path(ws)
    _check_world(ws, cfg)
    out = Path(cfg.out) if cfg.out is not None else ws / "datasets" / task_slug(cfg.task)
    source = SimSourceConfig(
        world=str(ws.resolve()), task=cfg.task, size=tuple(cfg.size), fps=cfg.fps, cameras=tuple(cfg.cameras),
        randomization=cfg.randomization,
    )  # fmt: skip
    run = RunConfig(
        episodes=cfg.episodes, seed=cfg.seed, max_attempts=cfg.max_attempts, workers=cfg.workers,
        ray_address=cfg.ray_address, format=cfg.format, preview=cfg.preview,
    )  # fmt: skip
    if source.robot_render_faces:  # build the render copy of the robot once, before workers race for it
        from ..world.config import load_world
        from .robot_proxy import lowpoly_robot
        from .sim_source import robot_cache_dir

        robot_file = load_world(ws).robot.file
        if robot_file.lower().endswith(".xml"):
            lowpoly_robot(robot_file, robot_cache_dir(), source.robot_render_faces)
    fingerprint = {**world_fingerprint(ws), "source": json.loads(json.dumps(source.to_json(), default=str))}
    summary = generate_dataset(out, SimSourceFactory(source), source.spec(), run, fingerprint,
                               {"task": cfg.task, "dataset": str(out)}, log, progress)  # fmt: skip
    return summary


BENCH_KEYS = ("demos_per_min", "success_rate", "episodes", "frames", "workers", "backend", "ms_per_frame")


def bench_datagen(
    ws: str | Path, cfg: GenerateConfig, runs: int = 1, log: Callable[[str], None] = print
) -> dict[str, Any]:
    """Generate ``cfg.episodes`` episodes ``runs`` times into throw-away folders; the medians over runs.

    ``demos_per_min`` counts successful episodes per minute of wall time with the workers warm (their
    one-off start-up - Genesis build, kernel and JIT caches - excluded, as ``startup_s`` reports);
    ``ms_per_frame`` is worker time per recorded frame (all cameras), failed attempts included.
    """
    ws = Path(ws)
    per_run = []
    for r in range(runs):
        out = ws / "datasets" / f".bench-datagen-{r}"
        shutil.rmtree(out, ignore_errors=True)
        try:
            s = generate(ws, replace(cfg, out=out, seed=cfg.seed + r, preview=0), log=log)
        finally:
            shutil.rmtree(out, ignore_errors=True)
        per_run.append(s)
        extra = ("startup_s", "wall_s", "cpu_s_per_demo", "demos_per_cpu_min", "stage_seconds_total")
        log(json.dumps({k: s.get(k) for k in (*BENCH_KEYS, *extra)}))

    def med(key):
        vals = [s[key] for s in per_run if s.get(key) is not None]
        return round(statistics.median(vals), 3) if vals else None

    return {
        "demos_per_min": med("demos_per_min"),
        "success_rate": med("success_rate"),
        "episodes": med("episodes"),
        "frames": med("frames"),
        "workers": cfg.workers,
        "backend": per_run[0]["backend"],
        "ms_per_frame": med("ms_per_frame"),
        "runs": runs,
        "size": list(cfg.size),
        "fps": cfg.fps,
        "task": cfg.task,
        "startup_s": med("startup_s"),
        "cpu_s_per_demo": med("cpu_s_per_demo"),
        "demos_per_cpu_min": med("demos_per_cpu_min"),
        "stage_seconds_total": per_run[-1].get("stage_seconds_total"),
    }

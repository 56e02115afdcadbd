"""``m2m bench datagen``: demonstrations per minute of generation itself (``datagen.generate``, the path `m2m
generate` runs), into throw-away folders."""

from __future__ import annotations

import json
import shutil
import statistics
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..datagen import GenerateConfig, generate

if TYPE_CHECKING:
    from ..sim.tasks import Task
    from ..world.config import WorldConfig

__all__ = ["BENCH_KEYS", "bench_datagen"]

BENCH_KEYS = ("demos_per_min", "success_rate", "episodes", "frames", "workers", "backend", "ms_per_frame",
              "round_trip_pct")  # fmt: skip


def bench_datagen(
    world: WorldConfig,
    task: Task,
    cfg: GenerateConfig,
    scratch: Path,
    runs: int = 1,
    log: Callable[[str], None] = print,
) -> dict[str, Any]:
    """Generate ``cfg.run.episodes`` episodes ``runs`` times into throw-away folders under ``scratch``; the medians
    over runs.

    ``demos_per_min`` counts successful episodes per minute of wall time with the workers warm (their
    one-off start-up - Genesis build, kernel and JIT caches - excluded, as ``startup_s`` reports);
    ``ms_per_frame`` is worker time per recorded frame (all cameras), failed attempts included.
    """
    per_run = []
    for r in range(runs):
        out = Path(scratch) / f".bench-datagen-{r}"
        shutil.rmtree(out, ignore_errors=True)
        try:
            s = generate(world, task, out, replace(cfg, run=replace(cfg.run, seed=cfg.run.seed + r, preview=0)),
                         log=log)  # fmt: skip
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
        "workers": cfg.run.workers,
        "backend": per_run[0]["backend"],
        "ms_per_frame": med("ms_per_frame"),
        "runs": runs,
        "size": list(cfg.episode.size),
        "fps": cfg.episode.fps,
        "task": task.text,
        "startup_s": med("startup_s"),
        "cpu_s_per_demo": med("cpu_s_per_demo"),
        "demos_per_cpu_min": med("demos_per_cpu_min"),
        "round_trip_pct": med("round_trip_pct"),  # returning the episodes to the parent: dataset.py
        "stage_seconds_total": per_run[-1].get("stage_seconds_total"),
        **({"splat_server": per_run[-1]["splat_server"]} if cfg.splat_server else {}),
    }

"""Generating a dataset: attempts in workers -> staging -> one LeRobot dataset + summary + preview.

``generate_dataset`` is the whole procedure for any episode source; ``generate`` (datagen/simulated.py)
binds it to a simulated world and a task. Output (DESIGN.md section 3):

    <out>/              a LeRobot dataset (v3.0 or v2.1)
    <out>/summary.json  requested / written / failed episodes, failure reasons, rates, timings
    <out>/preview.mp4, <out>/contact_sheet.png
    <out>/meta/m2m_episodes.jsonl   per episode: attempt, seed, randomisation record

The dataset folder appears complete or not at all; a killed run resumes (export/staging.py).
"""

from __future__ import annotations

import json
import shutil
import statistics
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from ..errors import M2MError
from ..export.lerobot import FORMATS
from ..export.spec import DatasetSpec
from ..export.staging import StagedEpisode, Staging, consolidate, staging_dir_for
from ..progress import progress_bar
from .preview import write_preview
from .runner import RunStats, SourceFactory, WorkerPool, run_attempts


class GenerateError(M2MError, RuntimeError):
    """Generation cannot start or finish; the message says what to change."""


@dataclass(frozen=True)
class RunConfig:
    """How many episodes, how they are run and written (not what an episode is: that is the source's).

    episodes      successful episodes wanted
    seed          run seed; attempt k uses attempt_seed(seed, k), so same seed -> same episodes
    max_attempts  give up after this many attempts (default 3 * episodes + 5)
    workers       parallel workers (processes, or Ray actors with ray_address)
    ray_address   None: local processes; "local": a private Ray instance; "auto" / "host:port": a cluster
    format        "lerobot-v3.0" or "lerobot-v2.1"
    preview       episodes shown in preview.mp4 / contact_sheet.png (0: none)
    """

    episodes: int
    seed: int = 0
    max_attempts: int | None = None
    workers: int = 1
    ray_address: str | None = None
    format: str = "lerobot-v3.0"
    preview: int = 4

    def check(self) -> None:
        if isinstance(self.episodes, bool) or not isinstance(self.episodes, int) or self.episodes < 1:
            raise GenerateError(f"--episodes must be a positive integer, got {self.episodes!r}")
        if self.workers < 1:
            raise GenerateError(f"--workers must be >= 1, got {self.workers}")
        if self.format not in FORMATS:
            raise GenerateError(f"--format {self.format!r} is not one of {', '.join(FORMATS)}")
        if self.max_attempts is not None and self.max_attempts < self.episodes:
            raise GenerateError(f"max_attempts {self.max_attempts} is below --episodes {self.episodes}")

    @property
    def attempts_limit(self) -> int:
        return self.max_attempts if self.max_attempts is not None else 3 * self.episodes + 5


def run_fingerprint(source: dict[str, Any], cfg: RunConfig) -> dict[str, Any]:
    """The fingerprint a dataset's summary.json records: its source's and the run's count, seed and format."""
    return json.loads(json.dumps({**source, "episodes": cfg.episodes, "seed": cfg.seed, "format": cfg.format,
                                  "max_attempts": cfg.attempts_limit}))  # fmt: skip


def check_output(out_dir: Path, fingerprint: dict[str, Any]) -> dict[str, Any] | None:
    """None if ``out_dir`` may be (re)written; the existing summary if it already holds exactly this
    dataset (a rerun of a finished run is a no-op); GenerateError if it holds anything else."""
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise GenerateError(f"{out_dir} exists and is not a folder; choose another dataset folder")
    if not out_dir.exists() or not any(out_dir.iterdir()):
        return None
    summary = out_dir / "summary.json"
    if summary.is_file():
        try:
            old = json.loads(summary.read_text(encoding="utf-8"))
        except ValueError:
            old = {}
        if old.get("fingerprint") == json.loads(json.dumps(fingerprint)):
            return old
    what = "another dataset" if (out_dir / "meta" / "info.json").is_file() else "other files"
    raise GenerateError(f"{out_dir} already holds {what}; choose another dataset folder (--out) or delete it first")


def _median(xs: list[float]) -> float | None:
    return statistics.median(xs) if xs else None


def _round_trip_pct(mine: list[dict[str, Any]]) -> float | None:
    """The share (%) of each worker's time from its first attempt's start to its last one's end spent between
    attempts - its result travelling back and being committed, the next attempt handed out -, over all workers: what
    returning episodes to the parent costs the throughput (start-up and the last attempts' uneven end left out).
    Each worker's own clock, so it holds for workers on other machines too."""
    by_worker: dict[Any, list[dict[str, Any]]] = {}
    for r in mine:
        if "worker_end" in r:
            by_worker.setdefault(r["worker"], []).append(r)
    span = gaps = 0.0
    for rs in by_worker.values():
        rs.sort(key=lambda r: r["t_start"])
        span += rs[-1]["worker_end"] - rs[0]["t_start"]
        gaps += sum(max(0.0, b["t_start"] - a["worker_end"]) for a, b in zip(rs, rs[1:], strict=False))
    return round(100.0 * gaps / span, 2) if span > 0 else None


def summarize(run: RunStats, cfg: RunConfig, fingerprint: dict[str, Any], extra: dict[str, Any]) -> dict[str, Any]:
    results = run.results
    tried = sorted(results)  # a prefix 0..K-1 of attempts (runner.py)
    failures = [results[a] for a in tried if not results[a].get("success")]
    written = [results[a] for a in run.selected]
    frames = sum(int(r["length"]) for r in written)
    # Timings of this call's attempts only (those read back from staging were timed by an earlier run).
    mine = [r for r in results.values() if "t_start" in r]
    stage_totals: dict[str, float] = {}
    for r in mine:
        for k, v in r.get("timings", {}).items():
            stage_totals[k] = stage_totals.get(k, 0.0) + float(v)
    mine_frames = sum(int(r.get("length", 0)) for r in mine if r.get("success"))
    mine_ok = sum(1 for r in mine if r.get("success"))
    busy = sum(r["t_end"] - r["t_start"] for r in mine)
    cpu = sum(r.get("cpu_s", 0.0) for r in mine)
    summary = {
        "requested": cfg.episodes,
        "episodes": len(run.selected),
        "attempts": len(tried),
        "failed": len(failures),
        "success_rate": len(run.selected) / len(tried) if tried else 0.0,
        "failure_reasons": dict(Counter(r.get("reason") or "unknown" for r in failures)),
        "frames": frames,
        "format": cfg.format,
        "seed": cfg.seed,
        "workers": run.workers,
        "backend": run.backend,
        "startup_s": round(run.startup_s, 3),
        "wall_s": round(run.wall_s, 3),
        "attempts_this_run": run.new_attempts,
        # Throughput of this call, workers warm (startup excluded), over the attempts it ran.
        "demos_per_min": round(60.0 * mine_ok / run.wall_s, 3) if run.wall_s > 0 and mine_ok else None,
        "ms_per_frame": round(1000.0 * busy / mine_frames, 2) if mine_frames else None,
        "seconds_per_attempt_median": _median([r["t_end"] - r["t_start"] for r in mine]),
        # CPU cost per successful demo (failed attempts included): on a machine shared with other work the
        # wall-clock rate above says little; 60 / cpu_s_per_demo is the rate per core given to the workers.
        "cpu_s_per_demo": round(cpu / mine_ok, 2) if mine_ok else None,
        "demos_per_cpu_min": round(60.0 * mine_ok / cpu, 3) if cpu > 0 and mine_ok else None,
        "round_trip_pct": _round_trip_pct(mine),
        "stage_seconds_total": {k: round(v, 3) for k, v in sorted(stage_totals.items())},
        "attempt_selection": {"selected": run.selected, "failed": [r["attempt"] for r in failures]},
        "fingerprint": fingerprint,
        **extra,
    }
    if len(run.selected) < cfg.episodes:
        summary["shortfall"] = (f"only {len(run.selected)} of {cfg.episodes} episodes succeeded in "
                                f"{len(tried)} attempts (the limit)")  # fmt: skip
    return summary


def generate_dataset(
    out_dir: Path,
    factory: SourceFactory,
    spec: DatasetSpec,
    cfg: RunConfig,
    fingerprint: dict[str, Any],
    extra_summary: dict[str, Any] | None = None,
    log: Callable[[str], None] = print,
    progress: bool = True,
    pool: WorkerPool | None = None,
) -> dict[str, Any]:
    """Generate ``cfg.episodes`` episodes from ``factory``'s source into ``out_dir``; returns summary.json.

    ``fingerprint`` names what is generated (task, world, render settings, seed, count, format): a
    rerun with the same fingerprint resumes a killed run or, if it finished, returns its summary.
    ``pool``: workers kept across datasets (``runner.WorkerPool``, with ``cfg``'s workers); None: this run's own.
    """
    cfg.check()
    if pool is not None and (pool.workers, pool.ray_address) != (cfg.workers, cfg.ray_address):
        raise ValueError(f"the pool runs {pool.workers} worker(s) (ray: {pool.ray_address}), the run asks for "
                         f"{cfg.workers} (ray: {cfg.ray_address})")  # a caller's bug, not input
    out_dir = Path(out_dir)
    fingerprint = run_fingerprint(fingerprint, cfg)
    existing = check_output(out_dir, fingerprint)
    if existing is not None:
        # A run killed after swapping the dataset in but before removing its staging area leaves the latter.
        shutil.rmtree(staging_dir_for(out_dir), ignore_errors=True)
        log(f"{out_dir} already holds this dataset ({existing.get('episodes')} episodes); nothing to do")
        return existing
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    t0 = time.time()
    with Staging.open(out_dir, spec, fingerprint) as staging:
        resumed = staging.committed()
        ok = sum(1 for r in resumed.values() if r.get("success"))
        if resumed:
            log(f"resuming: {len(resumed)} attempts ({ok} successful) already committed in {staging.root}")
        bar = None
        if progress:
            # named for its task: a run of several tasks shows one bar each
            bar = progress_bar(total=cfg.episodes, desc=str((extra_summary or {}).get("task", "episodes")), unit="ep",
                               dynamic_ncols=True, initial=min(cfg.episodes, ok))  # fmt: skip
            # the workers build the twin before the first episode: ~15 s, more on a first run
            if ok < cfg.episodes and (pool is None or not pool.running):
                bar.set_postfix_str(f"starting {max(cfg.workers, 1)} worker(s)")

        fails = [0]

        def on_result(r: dict[str, Any]) -> None:
            if bar is None:
                return
            if r.get("success"):
                bar.update(1)
            else:
                fails[0] += 1
            bar.set_postfix(failed=fails[0])

        try:
            run = run_attempts(factory, staging, cfg.episodes, cfg.seed, cfg.attempts_limit, cfg.workers,
                               cfg.ray_address, on_result, pool)  # fmt: skip
        finally:
            if bar is not None:
                bar.close()
        if not run.selected:
            reasons = Counter(r.get("reason") or "unknown" for r in run.results.values())
            raise GenerateError(f"no episode succeeded in {len(run.results)} attempts (reasons: {dict(reasons)}); "
                                f"nothing was written. The attempts are kept in {staging.root}")  # fmt: skip
        summary = summarize(run, cfg, fingerprint, extra_summary or {})

        def finish(tmp: Path, episodes: list[StagedEpisode]) -> None:
            lines = []
            for e, ep in enumerate(episodes):
                r = ep.result
                lines.append({"episode_index": e, "attempt": r["attempt"], "seed": r["seed"], "task": r["task"],
                              "length": r["length"], "record": r.get("record", {})})  # fmt: skip
            (tmp / "meta" / "m2m_episodes.jsonl").write_text("".join(json.dumps(x) + "\n" for x in lines))
            if cfg.preview:
                write_preview(tmp, episodes, spec, cfg.preview)
            summary["total_s"] = round(time.time() - t0, 3)
            (tmp / "summary.json").write_text(json.dumps(summary, indent=2), encoding="utf-8")

        consolidate(staging, out_dir, run.selected, cfg.format, finish)
    return summary


def config_dict(obj: Any) -> dict[str, Any]:
    """A dataclass as a JSON-ready dict (tuples -> lists) for fingerprints."""
    return json.loads(json.dumps(asdict(obj), default=str))

"""Runners (inline, worker processes, Ray), resume after SIGKILL, and output checks, driven by a
fake episode source (tests/datagen/datagen_fake.py, a test double: no simulator)."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import av
import numpy as np
import pyarrow.parquet as pq
import pytest
from datagen_fake import BUILDS_ENV, SPEC, FakeFactory

from mirage2matter.datagen import GenerateError, RunConfig, RunnerError, WorkerPool, generate_dataset
from mirage2matter.export import staging_dir_for, validate

FP = {"task": "grasp banana", "source": "fake"}
N = 6


def _generate(out: Path, **kw) -> dict:
    cfg = RunConfig(episodes=kw.pop("episodes", N), seed=kw.pop("seed", 7), **kw)
    return generate_dataset(out, FakeFactory(kw.pop("delay", 0.0)), SPEC, cfg, FP, log=lambda m: None, progress=False)


def _content(ds: Path) -> dict:
    """What a reader gets, exactly: the data rows and the per-episode records (seeds, randomisation)."""
    out = {"data": pq.read_table(ds / "data" / "chunk-000" / "file-000.parquet").to_pydict()}
    out["episodes"] = [json.loads(x) for x in (ds / "meta" / "m2m_episodes.jsonl").read_text().splitlines()]
    return out


def _frames(path: Path) -> np.ndarray:
    with av.open(str(path)) as c:
        return np.stack([f.to_ndarray(format="rgb24") for f in c.decode(c.streams.video[0])]).astype(np.float64)


def _same_dataset(a: Path, b: Path) -> None:
    """Same rows and records; the same pictures. (x264 is not always byte-identical run to run: about
    1 encode in 20 differed in a few bytes here, so the videos are compared decoded, to 40 dB.)"""
    assert _content(a) == _content(b)
    videos = sorted(p.relative_to(a) for p in (a / "videos").rglob("*.mp4"))
    assert videos == sorted(p.relative_to(b) for p in (b / "videos").rglob("*.mp4")) and videos
    for v in videos:
        fa, fb = _frames(a / v), _frames(b / v)
        assert fa.shape == fb.shape
        mse = np.mean((fa - fb) ** 2)
        assert mse == 0 or 10 * np.log10(255.0**2 / mse) > 40, v


def test_inline_and_process_runners_write_the_same_dataset(tmp_path: Path) -> None:
    s1 = _generate(tmp_path / "inline")
    s2 = _generate(tmp_path / "procs", workers=2)
    for ds, s in ((tmp_path / "inline", s1), (tmp_path / "procs", s2)):
        assert validate(ds) == []
        assert s["episodes"] == N and s["requested"] == N
        assert s["failed"] > 0 and s["failure_reasons"] == {"fake failure": s["failed"]}
        assert s["attempts"] == N + s["failed"]
        assert (ds / "preview.mp4").is_file() and (ds / "contact_sheet.png").is_file()
        assert json.loads((ds / "summary.json").read_text())["episodes"] == N
        assert not staging_dir_for(ds).exists()
    assert s1["backend"] == "inline" and s2["backend"] == "process" and s2["workers"] == 2
    assert s1["attempt_selection"] == s2["attempt_selection"]
    _same_dataset(tmp_path / "inline", tmp_path / "procs")
    # A different seed gives different episodes.
    _generate(tmp_path / "other", seed=8)
    assert _content(tmp_path / "other")["data"] != _content(tmp_path / "inline")["data"]


@pytest.mark.parametrize("workers", [1, 2])
def test_a_worker_pool_serves_several_tasks_building_each_source_once(tmp_path: Path, monkeypatch, workers) -> None:
    """The generate stage's pool: each worker builds its source once and serves every task's dataset (the source
    retargeted); the datasets are the ones a run with its own workers writes. A source that cannot take another
    run's episodes over (here: another delay) is built anew."""
    builds = tmp_path / "builds.txt"
    monkeypatch.setenv(BUILDS_ENV, str(builds))
    tasks = ("grasp banana", "press button", "grasp croissant")
    cfg = RunConfig(episodes=4, seed=7, workers=workers)

    def run(out: Path, factory: FakeFactory, pool: WorkerPool | None = None) -> dict:
        return generate_dataset(out, factory, SPEC, cfg, {**FP, "task": factory.task}, log=lambda m: None,
                                progress=False, pool=pool)  # fmt: skip

    with WorkerPool(workers) as pool:
        pooled = [run(tmp_path / "pool" / str(i), FakeFactory(task=t), pool) for i, t in enumerate(tasks)]
        assert len(builds.read_text().splitlines()) == workers  # one build per worker for three datasets
        run(tmp_path / "pool" / "slow", FakeFactory(delay=0.001, task="grasp banana"), pool)
        assert 0 < len(builds.read_text().splitlines()) - workers <= workers  # not retargetable: built anew
    if workers > 1:  # spawning the workers is the first run's start-up; the later runs have none
        assert pooled[0]["startup_s"] > 0.2 and max(s["startup_s"] for s in pooled[1:]) < 0.05, pooled
    for i, t in enumerate(tasks):
        run(tmp_path / "own" / str(i), FakeFactory(task=t))
        _same_dataset(tmp_path / "pool" / str(i), tmp_path / "own" / str(i))
        assert pq.read_table(tmp_path / "pool" / str(i) / "meta" / "tasks.parquet").to_pydict()["task"] == [t]
    assert validate(tmp_path / "pool" / "slow") == []
    with pytest.raises(ValueError, match="pool runs"):  # a pool of another size is a caller's bug
        run(tmp_path / "x", FakeFactory(), WorkerPool(workers + 1))


def test_v21_format_and_output_folder_rules(tmp_path: Path) -> None:
    out = tmp_path / "ds"
    s = _generate(out, format="lerobot-v2.1", episodes=3)
    assert validate(out) == [] and s["format"] == "lerobot-v2.1"
    assert json.loads((out / "meta" / "info.json").read_text())["codebase_version"] == "v2.1"
    # The same run again: already there, nothing rewritten.
    before = (out / "summary.json").stat().st_mtime_ns
    assert _generate(out, format="lerobot-v2.1", episodes=3)["episodes"] == 3
    assert (out / "summary.json").stat().st_mtime_ns == before
    # Anything else into that folder: refused, and the dataset is untouched.
    with pytest.raises(GenerateError, match="already holds another dataset"):
        _generate(out, episodes=4)
    assert validate(out) == [] and not staging_dir_for(out).exists()
    (tmp_path / "junk").mkdir()
    (tmp_path / "junk" / "notes.txt").write_text("mine")
    with pytest.raises(GenerateError, match="already holds other files"):
        _generate(tmp_path / "junk")
    with pytest.raises(GenerateError, match="--format"):
        _generate(tmp_path / "x", format="hdf5")


def test_ray_local_instance_matches_processes(tmp_path: Path) -> None:
    ray = pytest.importorskip("ray")
    import datagen_fake
    from ray import cloudpickle

    cloudpickle.register_pickle_by_value(datagen_fake)  # Ray workers cannot import the tests folder
    try:
        s = _generate(tmp_path / "ray", workers=2, ray_address="local", episodes=4)
    finally:
        ray.shutdown()
    assert s["backend"] == "ray" and validate(tmp_path / "ray") == []
    _generate(tmp_path / "inline", episodes=4)
    _same_dataset(tmp_path / "ray", tmp_path / "inline")


def test_unreachable_ray_address_is_a_clear_error(tmp_path: Path) -> None:
    pytest.importorskip("ray")
    t = time.time()
    with pytest.raises(RunnerError, match="no Ray cluster answers at 127.0.0.1:9"):
        _generate(tmp_path / "ds", ray_address="127.0.0.1:9")
    assert time.time() - t < 30
    assert not (tmp_path / "ds").exists()


_KILL_SCRIPT = """
import sys
sys.path.insert(0, {tests!r})
from pathlib import Path
from datagen_fake import BUILDS_ENV, SPEC, FakeFactory
from mirage2matter.datagen import RunConfig, generate_dataset
generate_dataset(Path({out!r}), FakeFactory({delay}), SPEC, RunConfig(episodes={n}, seed=7, workers=2),
                 {fp!r}, progress=False)
"""


def test_sigkill_midway_then_rerun_gives_exactly_n_episodes(tmp_path: Path) -> None:
    out = tmp_path / "ds"
    n = 8
    script = _KILL_SCRIPT.format(tests=str(Path(__file__).parent), out=str(out), delay=0.4, n=n, fp=FP)
    proc = subprocess.Popen([sys.executable, "-c", script], start_new_session=True)
    attempts = staging_dir_for(out) / "attempts"
    deadline = time.time() + 120
    while time.time() < deadline:
        done = [p for p in attempts.glob("attempt-*")] if attempts.is_dir() else []
        if len(done) >= 3:
            break
        time.sleep(0.05)
    else:
        proc.kill()
        pytest.fail("the generator committed no attempts within 120 s")
    os.killpg(proc.pid, signal.SIGKILL)  # the generator and its workers, mid-run
    proc.wait()
    assert not out.exists()  # no half-written dataset
    committed = len(list(attempts.glob("attempt-*")))
    assert 3 <= committed

    s = _generate(out, workers=2, episodes=n)  # the rerun resumes
    assert validate(out) == []
    info = json.loads((out / "meta" / "info.json").read_text())
    assert info["total_episodes"] == n == s["episodes"]
    assert s["attempts_this_run"] == s["attempts"] - committed  # nothing ran twice
    # Same episodes as a run that was never interrupted.
    _generate(tmp_path / "ref", episodes=n)
    _same_dataset(out, tmp_path / "ref")


_POOL_KILL_SCRIPT = """
import sys
sys.path.insert(0, {tests!r})
from pathlib import Path
from datagen_fake import SPEC, FakeFactory
from mirage2matter.datagen import RunConfig, WorkerPool, generate_dataset
with WorkerPool(2) as pool:
    for task in {tasks!r}:
        generate_dataset(Path({out!r}) / task, FakeFactory({delay}, task), SPEC, RunConfig(episodes={n}, seed=7,
                         workers=2), {{**{fp!r}, "task": task}}, progress=False, pool=pool)
"""


def _proc_stat(pid: int) -> tuple[str, int] | None:
    """(state, parent pid) of a live process, None once it is gone (a zombie counts as gone)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (FileNotFoundError, ProcessLookupError):
        return None
    return None if fields[0] in "ZX" else (fields[0], int(fields[1]))


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads processes from /proc (Linux)")
def test_a_pooled_run_killed_in_its_second_task_resumes_and_its_workers_die_with_it(tmp_path: Path) -> None:
    """The generate stage's shape: one pool of 2 worker processes for two tasks' datasets. SIGKILL to the generator
    alone (not its process group: what a killed terminal or an OOM kill of the parent does) while the second
    task's attempts are being committed: the workers exit with it and commit nothing after it (orphans would keep
    committing beside the rerun); the rerun keeps the first dataset, resumes the second, and both are the datasets
    of runs never interrupted."""
    out, n, tasks = tmp_path / "ds", 6, ("grasp banana", "press button")
    script = _POOL_KILL_SCRIPT.format(tests=str(Path(__file__).parent), out=str(out), delay=0.3, n=n, fp=FP,
                                      tasks=tasks)  # fmt: skip
    proc = subprocess.Popen([sys.executable, "-c", script], start_new_session=True)
    attempts = staging_dir_for(out / tasks[1]) / "attempts"
    try:
        deadline = time.time() + 120
        while len(list(attempts.glob("attempt-*"))) < 2:
            assert time.time() < deadline, "the generator committed no attempts of its second task within 120 s"
            assert proc.poll() is None, "the generator ended before its second task's attempts"
            time.sleep(0.02)
        workers = [int(p.name) for p in Path("/proc").iterdir() if p.name.isdigit() and
                   (st := _proc_stat(int(p.name))) and st[1] == proc.pid and
                   b"spawn_main" in Path(f"/proc/{p.name}/cmdline").read_bytes()]  # fmt: skip
        assert len(workers) == 2, workers
        proc.send_signal(signal.SIGKILL)  # the generator only
        proc.wait()
        deadline = time.time() + 10
        while any(_proc_stat(w) for w in workers):
            assert time.time() < deadline, "the workers outlived the generator"
            time.sleep(0.02)
    finally:
        with contextlib.suppress(ProcessLookupError):  # whatever of its session is left, if the test failed
            os.killpg(proc.pid, signal.SIGKILL)
    committed = len(list(attempts.glob("attempt-*")))
    time.sleep(1.0)  # > 3 attempts' delay: a surviving worker would have committed by now
    assert len(list(attempts.glob("attempt-*"))) == committed
    assert (out / tasks[0] / "meta" / "info.json").is_file() and not (out / tasks[1]).exists()
    first = (out / tasks[0] / "summary.json").stat().st_mtime_ns

    cfg = RunConfig(episodes=n, seed=7, workers=2)
    with WorkerPool(2) as pool:
        again = [generate_dataset(out / t, FakeFactory(0.3, t), SPEC, cfg, {**FP, "task": t}, log=lambda m: None,
                                  progress=False, pool=pool) for t in tasks]  # fmt: skip
    assert (out / tasks[0] / "summary.json").stat().st_mtime_ns == first  # kept, not redone
    assert again[1]["attempts_this_run"] == again[1]["attempts"] - committed  # nothing ran twice
    for t in tasks:
        assert validate(out / t) == []
        generate_dataset(tmp_path / "ref" / t, FakeFactory(task=t), SPEC, RunConfig(episodes=n, seed=7),
                         {**FP, "task": t}, log=lambda m: None, progress=False)  # fmt: skip
        _same_dataset(out / t, tmp_path / "ref" / t)


_SPAWN_ONLY_SCRIPT = """
import json, multiprocessing as mp, sys
sys.path.insert(0, {tests!r})
from pathlib import Path
from datagen_fake import SPEC, FakeFactory, SpawnOnlyFactory
from mirage2matter.datagen import RunConfig, RunnerError, WorkerPool, generate_dataset
if __name__ == "__main__":
    cfg = RunConfig(episodes=4, seed=7, workers=2)
    lock = mp.get_context("spawn").Lock()
    s = generate_dataset(Path({out!r}) / "own", SpawnOnlyFactory(inherited=lock), SPEC, cfg, {fp!r}, log=print,
                         progress=False)
    refused = None
    with WorkerPool(2) as pool:
        generate_dataset(Path({out!r}) / "first", FakeFactory(), SPEC, cfg, {fp!r}, log=print, progress=False,
                         pool=pool)
        try:
            generate_dataset(Path({out!r}) / "second", SpawnOnlyFactory(task="press button", inherited=lock), SPEC,
                             cfg, {{**{fp!r}, "task": "press button"}}, log=print, progress=False, pool=pool)
        except RunnerError as e:
            refused = str(e)
    print(json.dumps({{"episodes": s["episodes"], "refused": refused}}))
"""


def test_a_source_that_pickles_only_at_spawn_runs_on_its_own_workers_and_is_refused_by_a_pool(tmp_path: Path) -> None:
    """generate --splat-server's shape: a factory holding what pickles only into a process as it is spawned (the
    server's queues and buffers; here a lock). Its own worker processes run it (its attempts must not carry it
    through the task queue, whose feeder thread drops what it cannot pickle: the run waited forever), and a pool
    started for another run refuses it with a clear error instead of hanging."""
    out = tmp_path / "ds"
    script = tmp_path / "spawn_only.py"
    script.write_text(_SPAWN_ONLY_SCRIPT.format(tests=str(Path(__file__).parent), out=str(out), fp=FP))
    proc = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True, start_new_session=True)
    try:
        stdout, _ = proc.communicate(timeout=90)  # ~7 s here
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
        pytest.fail("generation with a spawn-only source hung (its attempts never reached the workers)")
    assert proc.returncode == 0, stdout
    result = json.loads(stdout.strip().splitlines()[-1])
    assert result["episodes"] == 4 and validate(out / "own") == []
    _generate(tmp_path / "ref", episodes=4)
    _same_dataset(out / "own", tmp_path / "ref")
    assert result["refused"] and "cannot be sent to workers started for another run" in result["refused"]
    assert not (out / "second").exists()


def test_killed_after_the_swap_before_cleanup(tmp_path: Path) -> None:
    out = tmp_path / "ds"
    _generate(out, episodes=3)
    leftover = staging_dir_for(out)
    (leftover / "attempts").mkdir(parents=True)  # as if killed between the swap and removing the staging area
    s = _generate(out, episodes=3)
    assert s["episodes"] == 3 and validate(out) == [] and not leftover.exists()

"""One writer per workspace, outputs swapped in all at once: refused concurrent writers, kills at random points,
a full disk. After any of them the workspace holds the old outputs or the new ones, never a mix, a rerun
finishes the work, and no temporary is left behind."""

from __future__ import annotations

import fcntl
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from mirage2matter.stages import get_stage, run_stage
from mirage2matter.stages.base import Stage
from mirage2matter.stages.transaction import Transaction, WorkspaceBusy, workspace_lock
from mirage2matter.workspace import Workspace

M2M = [sys.executable, "-m", "mirage2matter"]


def _images(folder: Path, n: int = 12, seed: int = 0) -> Path:
    """A textured image drifting sideways: keyframes with parallax, no video decoding needed."""
    folder.mkdir(parents=True, exist_ok=True)
    base = np.random.default_rng(seed).integers(0, 255, (90, 120, 3), dtype=np.uint8)
    for i in range(n):
        Image.fromarray(np.roll(base, 4 * i, axis=1)).save(folder / f"{i:02d}.png")
    return folder


def _leftovers(root: Path) -> list[str]:
    """Temporaries of atomic writes and unfinished transactions below ``root``."""
    temps = [str(p.relative_to(root)) for p in root.rglob("*") if ".tmp-" in p.name or ".old-" in p.name]
    txn = root / ".m2m" / "txn"
    return temps + ([f".m2m/txn/{p.name}" for p in txn.iterdir()] if txn.is_dir() else [])


def test_a_failed_stage_leaves_the_workspace_as_it_was(tmp_path):
    ws = Workspace(tmp_path / "ws")
    stage = get_stage("capture")
    cfg = stage.config(source=_images(tmp_path / "a"), max_keyframes=8, min_parallax_px=0.0)
    run_stage(stage, ws, cfg, log=lambda s: None)
    before = {p: p.read_bytes() for p in ws.capture_dir.iterdir()}
    bad = _images(tmp_path / "b", n=3)  # fewer images than min_keyframes
    with pytest.raises(Exception, match="min_keyframes"):
        run_stage(stage, ws, stage.config(source=bad, max_keyframes=8), log=lambda s: None)
    assert {p: p.read_bytes() for p in ws.capture_dir.iterdir()} == before
    assert not _leftovers(ws.root) and not (ws.root / ".m2m").exists()


def test_outputs_are_swapped_in_together_and_a_killed_swap_is_finished(tmp_path):
    ws = Workspace(tmp_path / "ws")
    (ws.root / "calib").mkdir(parents=True)
    (ws.root / "calib" / "a.json").write_text("old a")
    (ws.root / "calib" / "b.json").write_text("old b")
    with workspace_lock(ws):
        txn = Transaction(ws, "demo", [Path("calib/a.json"), Path("calib/b.json")])
        txn.begin("k1")
        staged = txn.staged_ws
        assert staged.path("calib", "a.json") != ws.path("calib", "a.json")
        assert staged.path("capture") == ws.path("capture")  # what the stage does not write is read in place
        staged.path("calib", "a.json").write_text("new a")
        staged.path("calib", "b.json").write_text("new b")
        # a kill in the middle of the swap: the journal says "committing", one file is in
        txn._rename_paths()
        txn._write_journal(state="committing")
        os.replace(staged.path("calib", "a.json"), ws.path("calib", "a.json.x"))
        os.replace(ws.path("calib", "a.json"), txn.dir / "aside")
        os.replace(ws.path("calib", "a.json.x"), ws.path("calib", "a.json"))
    assert (ws.root / "calib" / "b.json").read_text() == "old b"
    with workspace_lock(ws):  # the next transaction of that name finishes the swap first
        Transaction(ws, "demo", [Path("calib/a.json"), Path("calib/b.json")]).begin("k2")
    assert (ws.root / "calib" / "a.json").read_text() == "new a"
    assert (ws.root / "calib" / "b.json").read_text() == "new b"


def test_a_second_writer_is_refused_naming_the_first(tmp_path):
    ws = Workspace(tmp_path / "ws")
    src = _images(tmp_path / "img")
    with workspace_lock(ws, "m2m capture (test)"):
        r = subprocess.run([*M2M, "capture", str(src), "-w", str(ws.root)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, r.stderr
    assert f"being written by pid {os.getpid()} (`m2m capture (test)`" in r.stderr
    assert not ws.capture_dir.exists()
    ws.root.mkdir()
    fd = os.open(ws.root, os.O_RDONLY)  # another holder of the same folder's lock, in this process
    fcntl.flock(fd, fcntl.LOCK_EX)
    try:
        with pytest.raises(WorkspaceBusy, match="being written by another process"), workspace_lock(ws):
            pass
    finally:
        os.close(fd)


def test_two_edits_at_once_lose_nothing(sample_world_ws, tmp_path):
    """Two `m2m world move` of different objects started together: one is refused or both run, one after the
    other; every edit that reported success is in world.yaml."""
    from mirage2matter.world import load_world

    ws = tmp_path / "ws"
    shutil.copytree(sample_world_ws(gaussians_per_object=3000, scene_density_per_m2=4000.0), ws)
    before = load_world(ws / "world")
    moves = {"banana": "0,-0.02,0", "croissant": "0,0.02,0"}
    procs = {n: subprocess.Popen([*M2M, "world", "move", "-w", str(ws), "--name", n, "--by", d],
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for n, d in moves.items()}  # fmt: skip
    results = {n: (p.wait(timeout=300), p.stderr.read()) for n, p in procs.items()}
    after = load_world(ws / "world")
    for name, (rc, err) in results.items():
        moved = np.linalg.norm(after.object(name).placement.translation - before.object(name).placement.translation)
        if rc == 0:
            assert moved == pytest.approx(0.02, abs=1e-9), name
        else:
            assert rc == 2 and "being written by" in err, err
            assert moved == 0.0
    assert any(rc == 0 for rc, _ in results.values())
    assert not _leftovers(ws)


def _kill_after(args: list[str], seconds: float) -> int:
    p = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        return p.wait(timeout=seconds)
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGKILL)
        p.wait()
        return -9


@pytest.fixture(scope="module")
def imported_ws(tmp_path_factory, sample_dir) -> Path:
    """A workspace with capture/ and sfm/ imported from 16 ground-truth-posed sample frames (half size)."""
    from mirage2matter.sample.transforms import write_sample_transforms

    root = tmp_path_factory.mktemp("kill")
    tf = write_sample_transforms(sample_dir, root / "data", every=45, scale=0.5)
    assert subprocess.run([*M2M, "sfm", "-w", str(root / "ws"), "--from-transforms", str(tf)], capture_output=True,
                          timeout=300).returncode == 0  # fmt: skip
    return root / "ws"


@pytest.mark.parametrize("kill_at", [2.0, 6.0, 10.0])
def test_scene_training_killed_anywhere_resumes_and_finishes(imported_ws, tmp_path, kill_at):
    """train-scene with checkpoints, SIGKILLed at a point of the run: the committed scene/ is absent (never
    half there); the rerun resumes or redoes and commits a complete scene; nothing temporary is left."""
    ws = tmp_path / "ws"
    shutil.copytree(imported_ws, ws)
    args = [*M2M, "train-scene", "-w", str(ws), "--iterations", "60", "--downscale", "4", "--max-gaussians", "5000",
            "--checkpoint-every", "5"]  # fmt: skip
    rc = _kill_after(args, kill_at)
    scene = ws / "scene"
    if rc == -9:  # killed: scene/ absent, or whole when the kill came after the commit (before the exit)
        assert not scene.exists() or (json.loads((scene / "metrics.json").read_text())["iterations"] == 60
                                      and (scene / "gaussians.ply").is_file()), "a killed run left a partial scene/"
    else:
        assert rc == 0 and (scene / "gaussians.ply").is_file()
    r = subprocess.run(args, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    metrics = json.loads((scene / "metrics.json").read_text())
    assert metrics["iterations"] == 60 and (scene / "gaussians.ply").is_file()
    assert json.loads((ws / "pipeline.json").read_text())["scene"]["summary"]["iterations"] == 60
    assert not _leftovers(ws)


def _small_tmpfs(path: Path, size_kb: int) -> bool:
    path.mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size_kb}k", "tmpfs", str(path)], capture_output=True)
    return r.returncode == 0


def test_a_full_disk_fails_an_edit_cleanly(sample_world_ws, tmp_path):
    """On a file system with too little room for the new world.ply, `m2m world move` fails with a clear error
    and world.yaml and world.ply stay as they were (it used to save world.yaml and not world.ply)."""
    from mirage2matter.cli import main

    src = sample_world_ws(gaussians_per_object=3000, scene_density_per_m2=4000.0)
    used = sum(p.stat().st_size for p in src.rglob("*") if p.is_file())
    disk = tmp_path / "disk"
    if not _small_tmpfs(disk, (used + 200_000) // 1024):  # room for the world, not for its world.ply (MBs)
        pytest.skip("mounting a small tmpfs needs root (CAP_SYS_ADMIN)")
    try:
        ws = disk / "ws"
        shutil.copytree(src, ws)
        files = {p: p.read_bytes() for p in ws.rglob("*") if p.is_file()}
        rc = main(["world", "move", "-w", str(ws), "--name", "banana", "--by", "0,-0.02,0"])
        assert rc == 2
        assert {p: p.read_bytes() for p in ws.rglob("*") if p.is_file()} == files
        assert not _leftovers(ws)
    finally:
        subprocess.run(["umount", str(disk)], capture_output=True)


def _side_stage() -> Stage:
    """A stage run once per output name and outside pipelines (as train-policy, eval-policy): it writes
    side/<name>/out.txt, after waiting for the file ``gate`` when given."""
    import types
    from dataclasses import dataclass

    mod = types.ModuleType("mirage2matter.stages._side_test")

    @dataclass
    class Config:
        name: str = "a"
        gate: str = ""
        started: str = ""

    def run(ws, cfg, log):
        if cfg.started:
            Path(cfg.started).write_text("started")
        for _ in range(600):
            if not cfg.gate or Path(cfg.gate).exists():
                break
            time.sleep(0.1)
        out = ws.path("side", cfg.name, "out.txt")
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(cfg.name)
        return {"line": cfg.name}

    mod.Config, mod.run = Config, run
    mod.inputs = lambda ws, cfg: []
    mod.outputs = lambda ws, cfg: [ws.path("side", cfg.name, "out.txt")]
    mod.writes = lambda ws, cfg: [ws.path("side", cfg.name)]
    mod.record_key = lambda ws, cfg: f"side/{cfg.name}"
    sys.modules[mod.__name__] = mod
    return Stage(name="_side_test", command="side", help="", pipeline=False)


def _fork_stage(ws: Workspace, cfg) -> int:
    """run_stage(side stage, ws, cfg) in a forked child; its pid (exit status 0 when it committed)."""
    pid = os.fork()
    if pid == 0:  # the child: no pytest teardown, its own exit status
        code = 1
        try:
            run_stage(_side_stage(), ws, cfg, log=lambda s: None)
            code = 0
        finally:
            os._exit(code)
    return pid


def _wait_for(path: Path, seconds: float = 60.0) -> None:
    t0 = time.monotonic()
    while not path.exists():
        assert time.monotonic() - t0 < seconds, f"{path} never appeared"
        time.sleep(0.05)


def test_policy_stages_run_side_by_side_and_one_output_is_run_once(tmp_path):
    """Two trainings (or evaluations) of one workspace run at once, each committing when it finishes; a second
    run of the same output, and any other writer, are refused naming the run; a killed run frees the workspace."""
    stage = _side_stage()
    cfg = stage.config
    ws = Workspace(tmp_path / "ws")
    gate, started = tmp_path / "gate", tmp_path / "started"
    a = _fork_stage(ws, cfg(name="a", gate=str(gate), started=str(started)))
    try:
        _wait_for(started)
        # b runs and commits while a is running
        assert run_stage(stage, ws, cfg(name="b"), log=lambda s: None) == ({"line": "b"}, False)
        assert (ws.root / "side" / "b" / "out.txt").read_text() == "b"
        assert not (ws.root / "side" / "a").exists()
        with pytest.raises(WorkspaceBusy, match=f"side-a is being run by pid {a} "):
            run_stage(stage, ws, cfg(name="a"), log=lambda s: None)
        with pytest.raises(WorkspaceBusy, match=f"in use by side-a: pid {a} "), workspace_lock(ws, "m2m sfm"):
            pass
        with workspace_lock(ws, alongside=True):  # bookkeeping (an m2m.yaml update) goes on beside it
            pass
        gate.write_text("go")
        assert os.waitpid(a, 0)[1] == 0
    finally:
        gate.write_text("go")
    records = json.loads(ws.record_file.read_text())
    assert {"side/a", "side/b"} <= set(records)
    assert (ws.root / "side" / "a" / "out.txt").read_text() == "a"
    assert not _leftovers(ws.root) and not (ws.root / ".m2m").exists()
    # a run killed mid-way leaves its staging to resume, and nothing that holds the workspace
    started.unlink()
    c = _fork_stage(ws, cfg(name="c", gate=str(tmp_path / "never"), started=str(started)))
    _wait_for(started)
    os.kill(c, signal.SIGKILL)
    os.waitpid(c, 0)
    with workspace_lock(ws, "m2m sfm"):
        pass
    assert run_stage(stage, ws, cfg(name="c"), log=lambda s: None)[0] == {"line": "c"}
    assert not _leftovers(ws.root) and not (ws.root / ".m2m").exists()


def test_a_policy_stage_starting_during_another_runs_bookkeeping_waits_for_it(tmp_path):
    """Seeds started together (sim2real's) meet each other's start or commit holding the workspace lock for a
    moment: a policy stage's start waits it out instead of failing; a pipeline writer is still refused at once."""
    stage = _side_stage()
    ws = Workspace(tmp_path / "ws")
    ws.root.mkdir()
    held = tmp_path / "held"
    pid = os.fork()
    if pid == 0:  # another run's commit: the lock, alongside, for 1.5 s
        try:
            with workspace_lock(ws, "m2m train-policy (commit)", alongside=True):
                held.write_text("held")
                time.sleep(1.5)
        finally:
            os._exit(0)
    try:
        _wait_for(held)
        with pytest.raises(WorkspaceBusy, match="train-policy \\(commit\\)"), workspace_lock(ws, "m2m sfm"):
            pass
        t0 = time.monotonic()
        assert run_stage(stage, ws, stage.config(name="b"), log=lambda s: None) == ({"line": "b"}, False)
        assert time.monotonic() - t0 >= 0.3  # it waited for the commit to finish
    finally:
        os.waitpid(pid, 0)
    assert (ws.root / "side" / "b" / "out.txt").read_text() == "b"

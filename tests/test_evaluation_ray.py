"""What an evaluation on Ray workers carries (``eval_workers``), without Ray: the world, the policy's checkpoint and
the sample's ground truth as content, every path of the job renamed to where a worker unpacked them; a file that
cannot be read is an error on the driver, before any worker starts. (The runs on a cluster:
tests/datagen/test_datagen_cluster.py.)"""

from __future__ import annotations

import dataclasses
import os
import shutil
from pathlib import Path

import pytest

from fixtures.sim2real_bench import evaluation, recorded_bench
from mirage2matter.datagen.shipping import ShipError
from mirage2matter.env.twin_env import make_config
from mirage2matter.eval_workers import EvalJob, PolicyRecipe


def _paths(value, seen=None) -> list[str]:
    """Every absolute path (Path or str) inside ``value`` (dataclasses, lists, dicts)."""
    seen = seen if seen is not None else set()
    if id(value) in seen:
        return []
    seen.add(id(value))
    if isinstance(value, Path | str):
        return [str(value)] if os.path.isabs(value) else []
    if isinstance(value, tuple | list):
        return [p for v in value for p in _paths(v, seen)]
    if isinstance(value, dict):
        return [p for v in value.values() for p in _paths(v, seen)]
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return [p for f in dataclasses.fields(value) for p in _paths(getattr(value, f.name), seen)]
    return []


def test_the_job_carries_the_world_the_checkpoint_and_the_ground_truth(sample_world_ws, sample_dir, tmp_path,
                                                                       monkeypatch) -> None:  # fmt: skip
    ws = tmp_path / "ws"
    shutil.copytree(sample_world_ws(gaussians_per_object=3000, scene_density_per_m2=4000.0) / "world", ws / "world")
    policy = tmp_path / "elsewhere" / "tiny"  # a policy folder outside the workspace
    policy.mkdir(parents=True)
    (policy / "policy.pt").write_bytes(b"weights")
    (policy / "checkpoint.pt").write_bytes(b"a training checkpoint: not needed to evaluate")
    monkeypatch.chdir(sample_dir.parent.parent)  # the sample named relative to here, as --ground-truth may be
    env = make_config(ws / "world" / "world.yaml", "grasp banana", renderer="ground_truth", size=32,
                      ground_truth=Path(os.path.relpath(sample_dir)))  # fmt: skip
    job = EvalJob(env, PolicyRecipe(paths=(str(policy),), how={"device": "cpu"}))

    shipped = job.portable()
    names = sorted(rel for s in (shipped.shipment, *shipped.others) for rel, _ in s.files)
    assert "policy.pt" in names and "ground_truth.json" in names and "checkpoint.pt" not in names
    assert "world/world.yaml" in names and not any("scene.mp4" in n for n in names)
    here = shipped.local()
    driver = (str(ws.resolve()), str(policy.resolve()), str(sample_dir.resolve()))
    paths = _paths(here)
    assert paths and not [p for p in paths if p.startswith(driver)]
    assert (Path(here.policy.paths[0]) / "policy.pt").read_bytes() == b"weights"
    truth = (sample_dir / "ground_truth.json").read_bytes()
    assert (Path(here.env.ground_truth) / "ground_truth.json").read_bytes() == truth
    assert Path(here.env.world.root).is_dir() and Path(here.env.world.root) != (ws / "world").resolve()

    # a file of the world gone: an error naming it, on the driver
    shutil.rmtree(ws / "world" / "assets")
    with pytest.raises(ShipError, match="assets"):
        job.portable()


def test_bench_sim2real_passes_the_ray_address_on(tmp_path, sample_dir, monkeypatch) -> None:
    """Every generation and evaluation of ``bench sim2real --ray-address`` runs on the cluster with its workers;
    the evaluations one after another in this process (``--parallel`` child processes would each join the cluster)."""
    from mirage2matter.bench import sim2real

    ws, calls = recorded_bench(tmp_path, monkeypatch, lambda cfg: evaluation(5, 10), first_seed_done=False)
    fake_run = sim2real._run_stage  # the stage runs recorded instead of run
    monkeypatch.setattr(sim2real, "_side_by_side", lambda ws_, name, cs, parallel, log: (
        [fake_run(name, ws_, c, log) for c in cs] if parallel == 1 or name != "eval_policy"
        else pytest.fail("evaluations side by side in child processes")))  # fmt: skip
    cfg = sim2real.Sim2RealConfig(sample=sample_dir, demos=(50,), ablation_demos=0, robot_ablation_demos=0,
                                  press_task="", seeds=1, episodes=10, workers=6, parallel=2,
                                  ray_address="head:6379")  # fmt: skip
    sim2real.run_sim2real(ws, cfg, log=lambda m: None)
    gens = [c for name, c in calls if name == "generate"]
    evals = [c for name, c in calls if name == "eval_policy"]
    assert gens and evals
    assert {(c.ray_address, c.workers) for c in gens + evals} == {("head:6379", 6)}

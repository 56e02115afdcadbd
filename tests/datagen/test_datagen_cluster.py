"""Generation and evaluation on a two-node Ray cluster (``ray.cluster_utils.Cluster``, both nodes on this machine)
whose workers cannot touch the workspace nor the driver's checkout: an audit hook installed in every worker
(``runtime_env``'s ``worker_process_setup_hook``) raises on any open of a file there. The world reaches them as
content, the package through ``runtime_env``, the attempts (episode records) come back as content and the driver
commits them: the dataset is the process runner's for the same seeds (valid for ``export.validate``, the reader
independent of our writer: LeRobot itself is not installed here), the evaluation's records and success figures a local
run's, and a worker killed mid-attempt, or a whole worker node removed mid-run, has its work run again elsewhere."""

from __future__ import annotations

import json
import os
import shutil
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from datagen_fake import BUILDS_ENV, SPEC, FakeFactory
from eval_fake import LineEnv, LineJob, policy
from test_datagen_runners import FP, _same_dataset

import mirage2matter
from mirage2matter.datagen import RunConfig, RunnerError, generate_dataset
from mirage2matter.datagen.ray_workers import package_runtime_env
from mirage2matter.eval_workers import evaluate_on_ray
from mirage2matter.evaluation import evaluate_policy
from mirage2matter.export import staging_dir_for, validate
from mirage2matter.ray_cluster import ActorCalls, ClusterError

CHECKOUT_SRC = Path(mirage2matter.__file__).resolve().parent


def _deny(roots: list[str], code_roots: list[str]):
    """A worker setup hook: an audit hook refusing file access under ``roots`` (any path event) and reads of code
    under ``code_roots`` (the package must come through runtime_env). A closure: pickled by value to the nodes."""

    def setup() -> None:
        import sys

        path_events = {"open", "os.mkdir", "os.rename", "os.replace", "os.remove", "os.rmdir", "os.listdir",
                       "os.scandir"}  # fmt: skip

        def hook(event: str, args: tuple) -> None:
            if event not in path_events:
                return
            for a in args[:2]:
                if isinstance(a, str | bytes | os.PathLike):
                    p = os.path.abspath(os.fsdecode(a))
                    bad = [r for r in roots if p == r or p.startswith(r + os.sep)]
                    if event == "open":
                        bad += [r for r in code_roots if p.startswith(r + os.sep)]
                    if bad:
                        raise PermissionError(f"worker touched {p} ({event}): workers share nothing with the driver")

        sys.addaudithook(hook)

    return setup


@pytest.fixture
def cluster(tmp_path: Path):
    """A head and one worker node, one CPU each; a driver connected with the audit hook for the workers."""
    ray = pytest.importorskip("ray")
    import datagen_fake
    import eval_fake
    from ray import cloudpickle
    from ray.cluster_utils import Cluster

    for fake in (datagen_fake, eval_fake):
        cloudpickle.register_pickle_by_value(fake)  # Ray workers cannot import the tests folder
    ws = (tmp_path / "ws").resolve()
    c = Cluster(initialize_head=True, head_node_args={"num_cpus": 1, "include_dashboard": False})
    try:
        c.add_node(num_cpus=1)
        c.wait_for_nodes()
        hook = _deny([str(ws)], [str(CHECKOUT_SRC)])
        ray.init(address=c.address, log_to_driver=False,
                 runtime_env={**package_runtime_env(), "worker_process_setup_hook": hook})  # fmt: skip
        yield c, ws
    finally:
        ray.shutdown()
        c.shutdown()


def test_two_nodes_sharing_nothing_write_the_process_runners_dataset(cluster, tmp_path: Path) -> None:
    c, ws = cluster
    texture = ws / "world" / "texture.bin"
    texture.parent.mkdir(parents=True)
    texture.write_bytes(os.urandom(256))
    n = 4
    cfg = RunConfig(episodes=n, seed=7, workers=2, ray_address=c.address)

    # The hook works: a source that reads the workspace from a worker (no portable()) never starts.
    class Unshipped(FakeFactory):
        portable = None

    with pytest.raises(RunnerError, match="failed while starting(.|\n)*worker touched"):
        generate_dataset(ws / "refused", Unshipped(texture=str(texture)), SPEC, cfg, FP, log=lambda m: None,
                         progress=False)  # fmt: skip

    marker = tmp_path / "died"  # outside the workspace: the fake's "kill me once" flag
    factory = FakeFactory(texture=str(texture), die_at=2, die_marker=str(marker))
    s = generate_dataset(ws / "ray", factory, SPEC, cfg, FP, log=lambda m: None, progress=False)
    assert marker.exists(), "no worker died: the retry was not exercised"
    assert s["backend"] == "ray" and s["episodes"] == n
    assert validate(ws / "ray") == [] and not staging_dir_for(ws / "ray").exists()

    ref = tmp_path / "procs"
    generate_dataset(ref, FakeFactory(texture=str(texture)), SPEC, RunConfig(episodes=n, seed=7, workers=2), FP,
                     log=lambda m: None, progress=False)  # fmt: skip
    _same_dataset(ws / "ray", ref)
    assert json.loads((ws / "ray" / "summary.json").read_text())["attempt_selection"] == s["attempt_selection"]


def _worker_node(c):
    (node,) = c.worker_nodes
    return node


def test_a_worker_node_removed_mid_run_leaves_the_same_dataset(cluster, tmp_path: Path, monkeypatch) -> None:
    """The node goes once both workers are running attempts (1 s each): its attempt runs again on the head's worker
    (a replacement cannot start: no room left), and the dataset is the process runner's."""
    c, ws = cluster
    texture = ws / "world" / "texture.bin"
    texture.parent.mkdir(parents=True)
    texture.write_bytes(os.urandom(256))
    builds = tmp_path / "builds.txt"
    monkeypatch.setenv(BUILDS_ENV, str(builds))  # an M2M_ variable: the workers get it

    def remove_when_running() -> None:
        while not builds.is_file() or len(builds.read_text().splitlines()) < 2:
            time.sleep(0.05)
        time.sleep(0.5)  # mid-attempt
        c.remove_node(_worker_node(c))

    reruns, close = [], ActorCalls.close  # how many attempts ran again, read as the workers are closed
    monkeypatch.setattr(ActorCalls, "close", lambda self: (reruns.append(self.rerun), close(self))[1])
    killer = threading.Thread(target=remove_when_running, daemon=True)
    killer.start()
    n = 4
    cfg = RunConfig(episodes=n, seed=11, workers=2, ray_address=c.address)
    s = generate_dataset(ws / "ray", FakeFactory(delay=1.0, texture=str(texture)), SPEC, cfg, FP, log=lambda m: None,
                         progress=False)  # fmt: skip
    killer.join(timeout=5)
    assert not killer.is_alive() and not c.worker_nodes, "the node was not removed during the run"
    assert sum(reruns) >= 1, "no attempt was lost with the node"
    assert s["episodes"] == n and validate(ws / "ray") == [] and not staging_dir_for(ws / "ray").exists()
    monkeypatch.delenv(BUILDS_ENV)
    ref = tmp_path / "procs"
    generate_dataset(ref, FakeFactory(texture=str(texture)), SPEC, RunConfig(episodes=n, seed=11, workers=2), FP,
                     log=lambda m: None, progress=False)  # fmt: skip
    _same_dataset(ws / "ray", ref)


def _what(rows: list[dict]) -> list[dict]:
    """The records without their wall-clock times."""
    return [{k: v for k, v in r.items() if k not in ("seconds", "max_step_seconds", "timings")} for r in rows]


def test_evaluation_on_two_nodes_sharing_nothing_gives_the_local_records(cluster, tmp_path: Path) -> None:
    c, ws = cluster
    world = ws / "world" / "world.bin"
    world.parent.mkdir(parents=True)
    world.write_bytes(os.urandom(64))
    quiet = {"log": lambda m: None, "progress": False, "keep_frames": 2}
    local, local_frames = evaluate_policy(LineEnv(str(world), 0.0), policy, 8, seed=3, **quiet)

    # The hook works: a job that reads the workspace from a worker (nothing shipped) never starts.
    class Unshipped(LineJob):
        def portable(self):
            return self

    with pytest.raises(ClusterError, match="failed while starting(.|\n)*worker touched"):
        evaluate_on_ray(Unshipped(str(world)), 8, c.address, workers=2, seed=3, **quiet)

    # Resumed after 3 episodes, with the worker node removed once the first new episode is back (steps of 0.2 s):
    # its episode runs again on the head's worker; the records, figures and pictures are the local run's.
    done, saved = local["runs"][:3], []

    def on_episode(row: dict) -> None:
        saved.append(row)
        if c.worker_nodes:
            c.remove_node(_worker_node(c))

    five, said = {**quiet, "keep_frames": 5}, []
    job = LineJob(str(world), delay=0.2)
    ray_summary, ray_frames = evaluate_on_ray(job, 8, c.address, workers=2, seed=3, done=done, on_episode=on_episode,
                                              **{**five, "log": said.append})  # fmt: skip
    assert not c.worker_nodes and sorted(r["seed"] for r in saved) == list(range(6, 11))
    assert any("1 episode(s) ran again" in m for m in said), said
    assert _what(ray_summary["runs"]) == _what(local["runs"])
    same = ("episodes", "successes", "success_rate", "wilson95", "mean_steps", "cut")
    assert {k: ray_summary[k] for k in same} == {k: local[k] for k in same}
    assert 0 < local["successes"] < 8
    # the pictures of the episodes this call ran (seeds 6..10), as a local resumed run keeps them
    resumed_frames = evaluate_policy(LineEnv(str(world), 0.0), policy, 8, seed=3, done=done, **five)[1]
    assert len(ray_frames) == len(resumed_frames) == 5 and len(local_frames) == 2
    for a, b in zip(ray_frames, resumed_frames, strict=True):
        assert np.array_equal(np.stack(a), np.stack(b))


def test_eval_policy_on_the_cluster_writes_the_local_report(cluster, sample_world_ws, tmp_path: Path) -> None:
    """``m2m eval-policy --ray-address`` with the twin and a trained policy: the world and the checkpoint reach the
    workers as content (the hook refuses the workspace), the records and figures are the local run's."""
    from mirage2matter.cli import main

    c, ws = cluster
    shutil.copytree(sample_world_ws(gaussians_per_object=3000, scene_density_per_m2=4000.0) / "world", ws / "world")
    assert main(["generate", "-w", str(ws), "--task", "grasp banana", "--episodes", "1", "--size", "32"]) == 0
    assert main(["train-policy", "-w", str(ws), "--steps", "2", "--batch-size", "4", "--image-size", "32",
                 "--val-fraction", "0", "--name", "tiny"]) == 0  # fmt: skip
    args = ["eval-policy", "-w", str(ws), "--policy", "tiny", "--episodes", "3", "--horizon", "3",
            "--video-episodes", "1"]  # fmt: skip
    assert main([*args, "--name", "local"]) == 0
    assert main([*args, "--name", "ray", "--ray-address", c.address, "--workers", "2"]) == 0
    read = lambda name: json.loads((ws / "evals" / name / "summary.json").read_text())  # noqa: E731
    local, ray = read("local"), read("ray")
    assert _what(ray.pop("runs")) == _what(local.pop("runs"))
    same = ("episodes", "successes", "success_rate", "wilson95", "mean_steps", "cut", "size", "task", "inference")
    assert {k: ray[k] for k in same} == {k: local[k] for k in same}
    lines = lambda name: (ws / "evals" / name / "episodes.jsonl").read_text().splitlines()  # noqa: E731
    assert _what([json.loads(x) for x in lines("ray")]) == _what([json.loads(x) for x in lines("local")])
    assert (ws / "evals" / "ray" / "rollout.mp4").is_file()

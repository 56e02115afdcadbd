"""Generation on a two-node Ray cluster (``ray.cluster_utils.Cluster``, both nodes on this machine) whose workers
cannot touch the workspace nor the driver's checkout: an audit hook installed in every worker (``runtime_env``'s
``worker_process_setup_hook``) raises on any open of a file there. The world reaches them as content, the package
through ``runtime_env``, the attempts come back as content and the driver commits them: the dataset is the process
runner's for the same seeds, and a worker killed mid-attempt has its attempt run again elsewhere."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
from datagen_fake import SPEC, FakeFactory
from test_datagen_runners import FP, _same_dataset

import mirage2matter
from mirage2matter.datagen import RunConfig, RunnerError, generate_dataset
from mirage2matter.datagen.ray_workers import package_runtime_env
from mirage2matter.export import staging_dir_for, validate

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
    from ray import cloudpickle
    from ray.cluster_utils import Cluster

    cloudpickle.register_pickle_by_value(datagen_fake)  # Ray workers cannot import the tests folder
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

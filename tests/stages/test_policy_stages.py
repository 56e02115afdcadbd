"""``m2m train-policy`` -> ``m2m eval-policy`` on two generated demos of the sample world: the closed loop runs (not
its success rate), its report is complete and consistent, and bad input is a clear error that leaves no report."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from fixtures.policy_datasets import CAMERAS, build_dataset, tiny_config
from mirage2matter.cli import main
from mirage2matter.evaluation import wilson_interval
from mirage2matter.export import DatasetSpec

TASK = "grasp banana"


@pytest.fixture(scope="module")
def ws(sample_world_ws, tmp_path_factory) -> Path:
    """A workspace with the sample world, two 48-px demos of the grasp and a policy trained on them (6 steps)."""
    src = sample_world_ws(gaussians_per_object=3000, scene_density_per_m2=4000.0)
    ws = tmp_path_factory.mktemp("policy_ws")
    shutil.copytree(src / "world", ws / "world")
    assert main(["generate", "-w", str(ws), "--task", TASK, "--episodes", "2", "--size", "48", "--workers", "1"]) == 0
    assert main(["train-policy", "-w", str(ws), "--steps", "6", "--batch-size", "8", "--image-size", "32",
                 "--val-fraction", "0", "--name", "tiny"]) == 0  # fmt: skip
    return ws


def test_train_then_eval_in_the_hybrid_world(ws: Path, capsys) -> None:
    policy = ws / "policies" / "tiny"
    for f in ("policy.pt", "summary.json", "loss_curve.png"):
        assert (policy / f).is_file(), f
    trained = json.loads((policy / "summary.json").read_text())
    assert trained["steps"] == 6 and trained["episodes"]["train"] == 2
    assert trained["meta"]["robot_type"] == "franka_panda" and len(trained["meta"]["action_names"]) == 8

    assert main(["eval-policy", "-w", str(ws), "--policy", "tiny", "--episodes", "2", "--horizon", "4",
                 "--video-episodes", "1"]) == 0  # fmt: skip
    assert "'grasp banana' (hybrid):" in capsys.readouterr().out  # the task came from the policy's dataset
    report = ws / "evals" / "tiny-hybrid-grasp_banana"
    s = json.loads((report / "summary.json").read_text())
    rows = [json.loads(x) for x in (report / "episodes.jsonl").read_text().splitlines()]
    assert [r["seed"] for r in rows] == [1_000_000, 1_000_001] and s["episodes"] == 2
    assert all(1 <= r["steps"] <= 4 for r in rows) and s["size"] == 48  # the datasets' frame size
    assert s["successes"] == sum(r["success"] for r in rows)
    assert s["wilson95"] == pytest.approx(list(wilson_interval(s["successes"], 2)))
    from mirage2matter.video import read_video_frames

    frames = [f for _, _, f in read_video_frames(report / "rollout.mp4")]
    assert len(frames) == 1 + rows[0]["steps"] + 5 and frames[0].shape == (48, 96, 3)  # head | wrist, last held
    assert (report / "contact_sheet.png").is_file()

    assert s["inference"] == {"ensemble_decay": 0.1, "replan_every": None}  # the checkpoint's

    # the same settings again: nothing to do
    assert main(["eval-policy", "-w", str(ws), "--policy", "tiny", "--episodes", "2", "--horizon", "4",
                 "--video-episodes", "1"]) == 0  # fmt: skip
    assert "up to date" in capsys.readouterr().out

    # another way of running the chunks (the workspace's settings put back after: the flags persist in m2m.yaml)
    settings = (ws / "m2m.yaml").read_bytes()
    try:
        assert main(["eval-policy", "-w", str(ws), "--policy", "tiny", "--episodes", "1", "--horizon", "3",
                     "--video-episodes", "0", "--replan-every", "2", "--name", "replan"]) == 0  # fmt: skip
    finally:
        (ws / "m2m.yaml").write_bytes(settings)
    assert json.loads((ws / "evals" / "replan" / "summary.json").read_text())["inference"]["replan_every"] == 2

    # the mesh-only ablation's world (its objects drawn from their meshes), where such a policy was trained
    _eval_once(ws, settings, "--objects", "meshes")
    meshes = json.loads((ws / "evals" / "tiny-hybrid-mesh_objects-grasp_banana" / "summary.json").read_text())
    assert meshes["objects"] == "meshes" and meshes["episodes"] == 1

    # the world of a policy trained on supersampled demos (generate --supersample 2)
    _eval_once(ws, settings, "--supersample", "2")
    ss = json.loads((ws / "evals" / "tiny-hybrid-ss2-grasp_banana" / "summary.json").read_text())
    assert ss["supersample"] == 2 and ss["episodes"] == 1

    # episodes aimed at a corner of the placement region (--start-region): the banana starts in the box
    _eval_once(ws, settings, "--start-region", "banana:0.55,0.62,-0.3,-0.2")
    aimed = ws / "evals" / "tiny-hybrid-in-banana_0_55_0_62_m0_3_m0_2-grasp_banana"
    assert json.loads((aimed / "summary.json").read_text())["start_regions"] == ["banana:0.55,0.62,-0.3,-0.2"]
    x, y = json.loads((aimed / "episodes.jsonl").read_text().splitlines()[0])["start_xy"]["banana"]
    assert 0.53 <= x <= 0.64 and -0.32 <= y <= -0.18  # the body's origin, ~1 cm off its footprint's centre

    # an ensemble of two trained policies (their chunks averaged), its report named by its members
    try:
        assert main(["train-policy", "-w", str(ws), "--steps", "6", "--batch-size", "8", "--image-size", "32",
                     "--val-fraction", "0", "--seed", "1", "--name", "tiny1"]) == 0  # fmt: skip
        assert main(["eval-policy", "-w", str(ws), "--policy", "tiny,tiny1", "--episodes", "1", "--horizon", "2",
                     "--video-episodes", "0"]) == 0  # fmt: skip
    finally:
        (ws / "m2m.yaml").write_bytes(settings)
    ens = json.loads((ws / "evals" / "tiny+tiny1-hybrid-grasp_banana" / "summary.json").read_text())
    assert ens["policy"] == "tiny,tiny1" and ens["episodes"] == 1 and ens["size"] == 48
    assert ens["inference"] == {"ensemble_decay": 0.1, "replan_every": None, "combine": "mean"}


def test_generate_with_a_takeover_records_from_where_the_policy_left_the_world(ws: Path, capsys) -> None:
    """``generate --takeover tiny``: the policy acts first for its drawn number of ticks, the expert takes over and
    lifts the banana from there, and the dataset starts at the state the policy reached (replayed here in an
    environment of its own); the fingerprint holds the policy's content, and a missing policy is a clear error that
    leaves no dataset."""
    import hashlib

    import pyarrow.parquet as pq

    from mirage2matter.env import TwinEnv
    from mirage2matter.policy import load_policy

    out = ws / "datasets" / "takeover"
    settings = (ws / "m2m.yaml").read_bytes()
    try:
        assert main(["generate", "-w", str(ws), "--task", TASK, "--episodes", "1", "--size", "48", "--workers", "1",
                     "--takeover", "tiny", "--takeover-steps", "4,8", "--out", str(out)]) == 0  # fmt: skip
        err = _error(capsys, "generate", "-w", str(ws), "--task", TASK, "--episodes", "1", "--size", "48",
                     "--takeover", "nope", "--out", str(ws / "datasets" / "nope"))  # fmt: skip
        assert "generate --takeover" in err and "neither a policy in" in err
        assert "--takeover-steps: [9, 3] has its first value above its second; give lo,hi" in _error(
            capsys, "generate", "-w", str(ws), "--task", TASK, "--takeover", "tiny", "--takeover-steps", "9,3")
    finally:
        (ws / "m2m.yaml").write_bytes(settings)
    assert not (ws / "datasets" / "nope").exists()

    summary = json.loads((out / "summary.json").read_text())
    sha1 = hashlib.sha1((ws / "policies" / "tiny" / "policy.pt").read_bytes()).hexdigest()
    assert summary["fingerprint"]["source"]["takeover"] == {"steps": [4, 8], "sha1": [sha1]}
    (row,) = [json.loads(x) for x in (out / "meta" / "m2m_episodes.jsonl").read_text().splitlines()]
    took = row["record"]["takeover"]["step"]
    assert 4 <= took <= 8
    state = np.asarray(pq.read_table(next((out / "data").rglob("*.parquet"))).to_pydict()["observation.state"])
    assert state.shape[0] == row["length"]

    env = TwinEnv(ws / "world", TASK, size=48, horizon=None)
    try:
        obs, _ = env.reset(seed=row["seed"])
        start = obs["observation.state"].copy()
        policy = load_policy(ws / "policies" / "tiny", device="cpu")
        for _ in range(took):
            obs, *_ = env.step(policy(obs))
    finally:
        env.close()
    assert np.abs(state[0] - obs["observation.state"]).max() < 1e-3  # the recording starts where the policy left
    assert np.abs(state[0] - start).max() > 1e-2  # and that is not the episode's start: the policy moved the arm


def _eval_once(ws: Path, settings: bytes, *flags: str) -> None:
    """One 2-step hybrid episode of the tiny policy with ``flags``; the workspace's settings put back after (flags
    persist in m2m.yaml)."""
    try:
        assert main(["eval-policy", "-w", str(ws), "--policy", "tiny", "--episodes", "1", "--horizon", "2",
                     "--video-episodes", "0", *flags]) == 0  # fmt: skip
    finally:
        (ws / "m2m.yaml").write_bytes(settings)


@pytest.mark.slow
def test_eval_in_the_ground_truth_world(ws: Path, sample_dir: Path) -> None:
    assert main(["eval-policy", "-w", str(ws), "--policy", "tiny", "--episodes", "1", "--horizon", "3",
                 "--renderer", "ground_truth", "--ground-truth", str(sample_dir)]) == 0  # fmt: skip
    s = json.loads((ws / "evals" / "tiny-ground_truth-grasp_banana" / "summary.json").read_text())
    assert s["renderer"] == "ground_truth" and s["episodes"] == 1 and s["runs"][0]["steps"] <= 3


@pytest.mark.slow
def test_bench_policy_gap_records_the_expert_once_and_scores_both_renderers(
    ws: Path, sample_dir: Path, capsys, monkeypatch
) -> None:
    argv = ["bench", "policy-gap", "-w", str(ws), "--policy", "tiny", "--episodes", "1", "--size", "48",
            "--ground-truth", str(sample_dir)]  # fmt: skip
    assert main(argv) == 0
    result = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert result["episodes"] == 1 and result["expert_successes"] == 1  # the scripted grasp works here
    err = result["policies"]["tiny"]
    assert 0 < err["hybrid"] < 10 and 0 < err["ground_truth"] < 10
    assert err["gap"] == pytest.approx(err["ground_truth"] - err["hybrid"], abs=2e-5)
    assert (err["robot_look"], err["supersample"]) == ("auto", 1)  # as the policy's demos were drawn
    # keyed on the world's hash and on the ground truth's (another sample folder records anew)
    (folder,) = (ws / "evals" / "expert_pairs").glob("grasp_banana-48px-*-gt*")
    pair = np.load(folder / "pair_2000000.npz")
    n = len(pair["action"])
    for key in ("hybrid.head", "hybrid.wrist", "ground_truth.head", "ground_truth.wrist"):
        assert pair[key].shape == (n + 1, 48, 48, 3) and pair[key].dtype == np.uint8, key
    assert pair["state"].shape == (n + 1, 9) and bool(pair["success"])
    # the two renderers show the same scene, not the same pixels
    h, g = pair["hybrid.head"][0].astype(float), pair["ground_truth.head"][0].astype(float)
    assert 12.0 < 10 * np.log10(255**2 / np.mean((h - g) ** 2)) < 40.0

    import mirage2matter.bench.policy_gap as expert_pairs

    def no_recording(*a, **k):
        raise AssertionError("recorded again")

    monkeypatch.setattr(expert_pairs, "record_expert_pairs", no_recording)  # cached: the second run only scores
    assert main(argv) == 0
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1])["policies"] == result["policies"]


@pytest.mark.slow
def test_generate_through_the_ground_truth_draws_the_samples_own_pictures(ws: Path, sample_dir: Path) -> None:
    """``generate --renderer ground_truth`` (the sim-to-real bench's oracle): two worker processes, each drawing with
    the ground-truth renderer in a child of its own (its stall guard: a daemonic worker could not start one); the
    dataset's first frame is the truth's picture of that episode's start, not the hybrid world's; the fingerprint
    holds the ground truth's content."""
    import hashlib

    from mirage2matter.env import TwinEnv
    from mirage2matter.video import read_video_frames

    out = ws / "datasets" / "oracle"
    settings = (ws / "m2m.yaml").read_bytes()
    try:
        assert main(["generate", "-w", str(ws), "--task", TASK, "--episodes", "1", "--size", "48", "--workers", "2",
                     "--renderer", "ground_truth", "--ground-truth", str(sample_dir),
                     "--out", str(out)]) == 0  # fmt: skip
    finally:
        (ws / "m2m.yaml").write_bytes(settings)
    summary = json.loads((out / "summary.json").read_text())
    sha1 = hashlib.sha1((sample_dir / "ground_truth.json").read_bytes()).hexdigest()
    assert summary["fingerprint"]["source"]["ground_truth"] == {"sha1": sha1, "texture_filter": "trilinear"}
    (row,) = [json.loads(x) for x in (out / "meta" / "m2m_episodes.jsonl").read_text().splitlines()]
    _, _, first = next(read_video_frames(next((out / "videos" / "observation.images.head").rglob("*.mp4"))))

    def start_frame(**kw) -> np.ndarray:
        env = TwinEnv(ws / "world", TASK, size=48, horizon=None, **kw)
        try:
            obs, _ = env.reset(seed=row["seed"])
        finally:
            env.close()
        return obs["observation.images.head"].astype(float)

    def psnr(a: np.ndarray, b: np.ndarray) -> float:
        return float(10 * np.log10(255**2 / max(np.mean((a - b) ** 2), 1e-9)))

    truth, hybrid = start_frame(renderer="ground_truth", ground_truth=sample_dir), start_frame()
    assert psnr(first, truth) > 30.0  # the truth's picture, through H.264
    assert psnr(first, truth) > psnr(first, hybrid) + 5.0  # not the hybrid world's


def _error(capsys, *argv: str) -> str:
    assert main(list(argv)) == 2
    return capsys.readouterr().err


def test_bad_input_is_a_clear_error_and_leaves_no_report(ws: Path, sample_dir: Path, tmp_path: Path, capsys) -> None:
    w = str(ws)
    before = sorted(p.name for p in (ws / "evals").iterdir()) if (ws / "evals").is_dir() else []
    # ground truth on a capture without one (this workspace records no capture)
    err = _error(capsys, "eval-policy", "-w", w, "--policy", "tiny", "--renderer", "ground_truth")
    assert "has no ground truth" in err and "--renderer hybrid" in err
    err = _error(capsys, "eval-policy", "-w", w, "--policy", "tiny", "--renderer", "ground_truth",
                 "--ground-truth", str(tmp_path))  # fmt: skip
    assert "no ground_truth.json" in err
    # generation through a ground truth: none here, one that is not a sample, a hybrid-only setting with it
    settings = (ws / "m2m.yaml").read_bytes()
    gen = ("generate", "-w", w, "--task", TASK, "--episodes", "1", "--out", str(ws / "datasets" / "nope"),
           "--renderer", "ground_truth")  # fmt: skip
    try:
        err = _error(capsys, *gen)
        assert "generate --renderer ground_truth: this workspace's capture" in err and "--ground-truth DIR" in err
        assert "no ground_truth.json" in _error(capsys, *gen, "--ground-truth", str(tmp_path))
        assert "add --renderer ground_truth" in _error(capsys, *gen[:-2], "--ground-truth", str(sample_dir))
        err = _error(capsys, *gen, "--ground-truth", str(sample_dir), "--supersample", "2")
        assert "--supersample set(s) how the hybrid renderer draws" in err
    finally:
        (ws / "m2m.yaml").write_bytes(settings)
    assert not (ws / "datasets" / "nope").exists()
    # a task the world cannot run
    assert "no press button named 'banana'" in _error(capsys, "eval-policy", "-w", w, "--policy", "tiny",
                                                      "--task", "press banana")  # fmt: skip
    # a checkpoint that does not load
    broken = ws / "policies" / "broken"
    broken.mkdir(parents=True)
    (broken / "policy.pt").write_bytes(b"not a checkpoint")
    err = _error(capsys, "eval-policy", "-w", w, "--policy", "broken", "--task", TASK)
    assert "policy.pt does not load as a policy checkpoint" in err
    # a policy of another robot (6 joints)
    joints = tuple(f"j{i}" for i in range(6))
    build_dataset(tmp_path / "so100", DatasetSpec(joints, joints, "so100", fps=10, cameras=CAMERAS), length=12)
    from mirage2matter.policy import train_policy

    train_policy(tmp_path / "so100", tmp_path / "so100_policy", tiny_config(steps=3), log=lambda s: None,
                 progress=False)  # fmt: skip
    err = _error(capsys, "eval-policy", "-w", w, "--policy", str(tmp_path / "so100_policy"), "--task", TASK)
    assert "so100_policy" in err and "trained for robot_type 'so100', not 'franka_panda'" in err
    # inference settings that cannot apply
    assert "--ensemble-decay: -1.0 is out of range; allowed: a number in [0, 100]" in _error(
        capsys, "eval-policy", "-w", w, "--policy", "tiny", "--ensemble-decay", "-1")
    assert "replan_every must be in [1," in _error(capsys, "eval-policy", "-w", w, "--policy", "tiny",
                                                   "--replan-every", "99")  # fmt: skip
    assert "ensemble_combine medoid combines several policies" in _error(
        capsys, "eval-policy", "-w", w, "--policy", "tiny", "--ensemble-combine", "medoid")
    assert "a medoid ensemble needs three or more policies" in _error(
        capsys, "eval-policy", "-w", w, "--policy", f"tiny,{ws / 'policies' / 'tiny'}", "--ensemble-combine", "medoid")
    assert "some_pkg:act is a callable: leave them out" in _error(
        capsys, "eval-policy", "-w", w, "--policy", "some_pkg:act", "--task", TASK, "--ensemble-combine", "medoid")
    assert "the ground_truth renderer draws its own world" in _error(
        capsys, "eval-policy", "-w", w, "--policy", "tiny", "--renderer", "ground_truth", "--objects", "meshes")
    assert "add --supersample 0" in _error(capsys, "eval-policy", "-w", w, "--policy", "tiny", "--renderer",
                                           "ground_truth", "--supersample", "2")  # fmt: skip
    assert "--supersample: 9 is out of range; allowed: an integer in [0, 8]" in _error(
        capsys, "eval-policy", "-w", w, "--policy", "tiny", "--supersample", "9")
    assert "object:x_min,x_max,y_min,y_max" in _error(capsys, "eval-policy", "-w", w, "--policy", "tiny",
                                                      "--start-region", "banana:0.5")  # fmt: skip
    assert "outside the world's randomize region" in _error(capsys, "eval-policy", "-w", w, "--policy", "tiny",
                                                            "--start-region", "banana:1,2,0,0.1")  # fmt: skip
    # an unknown policy name
    assert "neither a policy in" in _error(capsys, "eval-policy", "-w", w, "--policy", "nope", "--task", TASK)
    assert "neither a policy in" in _error(capsys, "eval-policy", "-w", w, "--policy", "tiny,nope", "--task", TASK)
    assert "names each trained policy once" in _error(capsys, "eval-policy", "-w", w, "--policy", "tiny,tiny")
    after = sorted(p.name for p in (ws / "evals").iterdir()) if (ws / "evals").is_dir() else []
    assert after == before  # no half-written report

    # training: a dataset of another robot, more episodes than there are
    shutil.copytree(tmp_path / "so100", ws / "datasets" / "so100")
    try:
        err = _error(capsys, "train-policy", "-w", w, "--datasets", "so100", "--steps", "1", "--name", "x")
        assert "datasets/so100/meta/info.json" in err and "train on datasets generated in this world" in err
    finally:
        shutil.rmtree(ws / "datasets" / "so100")
    err = _error(capsys, "train-policy", "-w", w, "--datasets", TASK, "--episodes", "5", "--steps", "1", "--name", "x")
    assert "fewer than the 5 asked for" in err
    assert "dataset 'push kiwi'" in _error(capsys, "train-policy", "-w", w, "--datasets", "push kiwi", "--name", "x")
    assert not (ws / "policies" / "x").exists()


def test_eval_supersamples_as_the_policys_datasets_were_generated(tmp_path: Path) -> None:
    """eval-policy's hybrid world by default draws its splats as the policy's training demos were drawn (their
    dataset fingerprint's ``supersample``), so a policy trained on ``generate --supersample 4`` is evaluated in
    that world, not the classic one; an explicit setting wins; the ground_truth renderer draws its own."""
    from mirage2matter.stages.eval_policy import Config, supersample_of
    from mirage2matter.workspace import Workspace

    ws = Workspace(tmp_path / "ws")
    datasets = {}
    for name, splat in [("ss4", {"sh_degree": 1, "supersample": 4}), ("classic", {"sh_degree": 1})]:
        d = datasets[name] = tmp_path / name
        d.mkdir()
        (d / "summary.json").write_text(json.dumps({"fingerprint": {"source": {"hybrid": {"splat": splat}}}}))
    policies = {}
    for name, ds in [("a", "ss4"), ("b", "classic"), ("c", "gone")]:
        p = policies[name] = tmp_path / "policies" / name
        p.mkdir(parents=True)
        (p / "policy.pt").write_bytes(b"")
        (p / "summary.json").write_text(json.dumps({"datasets": [str(tmp_path / ds)]}))
    assert supersample_of(ws, Config(policy=str(policies["a"]))) == 4
    assert supersample_of(ws, Config(policy=str(policies["b"]))) == 1
    assert supersample_of(ws, Config(policy=str(policies["c"]))) == 1  # its datasets are gone: unknown, classic
    assert supersample_of(ws, Config(policy=str(policies["a"]), supersample=2)) == 2
    assert supersample_of(ws, Config(policy=str(policies["a"]), renderer="ground_truth")) == 1
    assert supersample_of(ws, Config(policy="my_pkg.glue:act")) == 1  # a user's callable


def test_eval_draws_the_robot_as_the_policys_datasets_were_generated(tmp_path: Path) -> None:
    """eval-policy's hybrid world draws the robot as the policy's demos drew it: a policy trained on ``generate
    --robot-look mesh`` is evaluated with the mesh robot (its report named so, apart from the Gaussian robot's), one
    trained on the default (no key in the fingerprint) with auto; an explicit setting wins; the ground_truth
    renderer draws its own robot, and a look given to it is a clear error."""
    from mirage2matter.policy.data import PolicyError
    from mirage2matter.stages.eval_policy import Config, report_name, robot_look_of
    from mirage2matter.workspace import Workspace

    ws = Workspace(tmp_path / "ws")
    for name, hybrid in [("mesh", {"robot_look": "mesh"}), ("default", {})]:
        d = tmp_path / name
        d.mkdir()
        (d / "summary.json").write_text(json.dumps({"task": TASK, "fingerprint": {"source": {"hybrid": hybrid}}}))
        p = tmp_path / "policies" / name
        p.mkdir(parents=True)
        (p / "policy.pt").write_bytes(b"")
        (p / "summary.json").write_text(json.dumps({"datasets": [str(d)]}))
    mesh, default = str(tmp_path / "policies" / "mesh"), str(tmp_path / "policies" / "default")
    assert robot_look_of(ws, Config(policy=mesh)) == "mesh"
    assert robot_look_of(ws, Config(policy=default)) == "auto"
    assert robot_look_of(ws, Config(policy=mesh, robot_look="gaussians")) == "gaussians"
    assert robot_look_of(ws, Config(policy=mesh, renderer="ground_truth")) == "auto"
    assert report_name(ws, Config(policy=mesh)) == "mesh-hybrid-mesh_robot-grasp_banana"
    assert report_name(ws, Config(policy=default)) == "default-hybrid-grasp_banana"  # the name it always had
    assert report_name(ws, Config(policy=mesh, renderer="ground_truth")) == "mesh-ground_truth-grasp_banana"
    with pytest.raises(PolicyError, match="robot_look=mesh is how the hybrid renderer draws the robot"):
        Config(policy=mesh, renderer="ground_truth", robot_look="mesh").validate()


def test_aimed_reports_are_named_by_their_boxes_with_signs(tmp_path: Path) -> None:
    from mirage2matter.stages.eval_policy import Config, report_name
    from mirage2matter.workspace import Workspace

    ws = Workspace(tmp_path / "ws")
    name = lambda *boxes: report_name(ws, Config(policy="my_pkg.glue:act", task="grasp banana", start_region=boxes))
    assert name("banana:0.4,0.5,-0.2,0.1") != name("banana:0.4,0.5,-0.2,-0.1")
    assert name("banana:0.4,0.5,-0.2,0.1") == "my_pkg_glue_act-hybrid-in-banana_0_4_0_5_m0_2_0_1-grasp_banana"
    assert name() == "my_pkg_glue_act-hybrid-grasp_banana"  # unaimed: the name it always had


def test_policy_stages_are_not_part_of_a_pipeline_run() -> None:
    from mirage2matter.stages import PIPELINE, STAGES

    names = [s.name for s in PIPELINE]
    assert names[-1] == "generate" and {"train_policy", "eval_policy"} <= {s.name for s in STAGES}
    assert np.all([s.pipeline for s in PIPELINE])

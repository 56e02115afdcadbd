"""bench sim2real's report: the paper's tables from the policies' evaluations, and its settings' checks."""

from __future__ import annotations

import pytest

from fixtures.sim2real_bench import evaluation as _e
from fixtures.sim2real_bench import recorded_bench
from mirage2matter.bench.sim2real import Sim2RealConfig, markdown_tables
from mirage2matter.errors import M2MError


def test_tables_hold_every_policy_with_its_interval(sample_dir):
    cfg = Sim2RealConfig(sample=sample_dir, task="grasp banana")
    rows = [
        {"kind": "main", "task": "grasp banana", "demos": 300, "seeds": 4, "ground_truth": _e(40), "hybrid": _e(45),
         "ground_truth_single": _e(38)},
        {"kind": "main", "task": "press button", "demos": 150, "ground_truth": _e(41), "hybrid": _e(49)},
        {"kind": "data_scale", "task": "grasp banana", "demos": 50, "ground_truth": _e(20)},
        {"kind": "data_scale", "task": "grasp banana", "demos": 150, "ground_truth": _e(35)},
        {"kind": "ablation", "task": "grasp banana", "demos": 150, "ground_truth": _e(30), "hybrid": _e(44)},
    ]  # fmt: skip
    md = markdown_tables({"policies": rows, "minutes": {"generation": 30.0, "training": 50.0, "evaluation": 60.0}},
                         cfg)  # fmt: skip
    assert "| grasp banana | 300 | 4 training seeds as one | 80.0 % [67-89] (40/50) | 90.0 % [79-96] (45/50) |" in md
    assert "| grasp banana | 300 | the first seed alone | 76.0 % [63-86] (38/50) | - |" in md
    assert "| press button | 150 | one training seed | 82.0 % [69-90] (41/50) | 98.0 % [90-100] (49/50) |" in md
    assert "| 3DGS (the method) | 70.0 % [56-81] (35/50) | - |" in md  # the Gaussian twin at 150 demos
    # and the ablation's policy in its own world: whether it learnt the task at all, beside the gap
    assert "| mesh only (vertex-coloured) | 60.0 % [46-72] (30/50) | 88.0 % [76-94] (44/50) |" in md
    scale = md.split("Data scale")[1]
    assert scale.index("| 50 |") < scale.index("| 150 |") < scale.index("| 300 |")
    assert "| 300 | 76.0 % [63-86] (38/50) |" in scale  # one seed, as the curve's other points
    assert "generation 30.0 min, training 50.0 min, evaluation 60.0 min" in md


def test_settings_are_checked(tmp_path, sample_dir):
    with pytest.raises(M2MError, match="no ground_truth.json"):
        Sim2RealConfig(sample=tmp_path).validate()
    with pytest.raises(M2MError, match="ablation_demos .* must be one of demos"):
        Sim2RealConfig(sample=sample_dir, ablation_demos=100).validate()
    for bad in ({"seeds": 0}, {"parallel": 0}):
        with pytest.raises(M2MError, match="seeds and parallel must be >= 1"):
            Sim2RealConfig(sample=sample_dir, **bad).validate()
    with pytest.raises(M2MError, match="steps must be >= 0"):
        Sim2RealConfig(sample=sample_dir, steps=-1).validate()


def test_the_bench_draws_its_demos_supersampled_and_records_the_scene(tmp_path, sample_dir, monkeypatch):
    """Every generation (main, press, ablation) gets the bench's supersample; the result says what scene it used."""
    from mirage2matter.bench import sim2real

    ws, calls = recorded_bench(tmp_path, monkeypatch)
    cfg = Sim2RealConfig(sample=sample_dir, demos=(50, 150), ablation_demos=150, episodes=10, supersample=3,
                         parallel=1)  # fmt: skip
    result = sim2real.run_sim2real(ws, cfg, log=lambda m: None)
    gens = [c for name, c in calls if name == "generate"]
    assert len(gens) == 3 and {c.supersample for c in gens} == {3}
    assert {c.objects for c in gens} == {"gaussians", "meshes"}
    assert result["scene"] == {"head_photo": "/x/head_view.png", "psnr_heldout": 29.7}
    assert "supersampling x3; the scene trained with the head camera's photo" in result["tables"]
    assert "with splat supersampling x3" in result["tables"]
    for bad in (0, 9):  # generate's own bound (1-8), said before the bench starts
        with pytest.raises(M2MError, match=f"supersample must be from 1 \\(off\\) to 8, got {bad}"):
            Sim2RealConfig(sample=sample_dir, supersample=bad).validate()


def test_the_robot_look_ablation_draws_the_mesh_robot_in_its_demos_and_own_world(tmp_path, sample_dir, monkeypatch):
    """With the robot's captured Gaussians in the world, the bench also trains the grasp on demos drawn with the mesh
    robot (``generate --robot-look mesh``), evaluates it in the ground-truth world and, with the mesh robot, in its own;
    the table sets it beside its Gaussian-robot twin of the same demo count. A world without robot Gaussians has no
    such ablation, and says so."""
    from mirage2matter.bench import sim2real

    scores = {"grasp_banana_150": 41, "grasp_banana_mesh_robot_150": 33}
    ws, calls = recorded_bench(tmp_path, monkeypatch, lambda cfg: _e(scores.get(cfg.name.split("-")[0], 30)),
                               robot_gaussians=True)  # fmt: skip
    cfg = Sim2RealConfig(sample=sample_dir, task="grasp banana", demos=(150,), seeds=1, press_task="",
                         ablation_demos=0, episodes=10, parallel=1)  # fmt: skip
    result = sim2real.run_sim2real(ws, cfg, log=lambda m: None)
    gens = [c for name, c in calls if name == "generate"]
    assert [(c.episodes, c.robot_look, c.out) for c in gens] == [
        (150, "auto", None), (150, "mesh", ws.dataset_dir("grasp_banana_mesh_robot"))]  # fmt: skip
    evals = {c.name: c for name, c in calls if name == "eval_policy"}
    assert evals["grasp_banana_mesh_robot_150-hybrid"].robot_look == "mesh"  # its own world: the mesh robot
    assert evals["grasp_banana_mesh_robot_150-ground_truth"].robot_look == "auto"  # the real one draws its own
    assert evals["grasp_banana_150-hybrid"].robot_look == "auto"
    md = result["tables"].split("Robot look")[1]
    assert "| its captured Gaussians (the method) | 82.0 % [69-90] (41/50) | 82.0 % [69-90] (41/50) |" in md
    assert "| the model's meshes (Genesis, composited) | 66.0 % [52-78] (33/50) | 66.0 % [52-78] (33/50) |" in md

    logs = []
    ws, calls = recorded_bench(tmp_path / "plain", monkeypatch)
    result = sim2real.run_sim2real(ws, cfg, log=logs.append)
    assert [c.robot_look for name, c in calls if name == "generate"] == ["auto"]
    assert "Robot look" not in result["tables"] and any("the world has no robot Gaussians" in m for m in logs)
    with pytest.raises(M2MError, match="robot_ablation_demos .* must be one of demos"):
        Sim2RealConfig(sample=sample_dir, robot_ablation_demos=100).validate()


def test_the_oracle_trains_the_recipe_on_the_ground_truths_own_pictures(tmp_path, sample_dir, monkeypatch):
    """``oracle_demos``: the task's demos drawn by the sample's ground-truth renderer (never supersampled, never on
    Ray), trained and evaluated like the method's policy of that demo count, set beside it in its own table; off by
    default, and it must have a hybrid twin."""
    from mirage2matter.bench import sim2real

    scores = {"grasp_banana_150": 30, "grasp_banana_ground_truth_150": 36}
    ws, calls = recorded_bench(tmp_path, monkeypatch, lambda cfg: _e(scores.get(cfg.name.split("-")[0], 20)))
    cfg = Sim2RealConfig(sample=sample_dir, task="grasp banana", demos=(150,), seeds=1, press_task="",
                         ablation_demos=0, robot_ablation_demos=0, oracle_demos=150, supersample=2, episodes=10,
                         parallel=1)  # fmt: skip
    result = sim2real.run_sim2real(ws, cfg, log=lambda m: None)
    gens = [c for name, c in calls if name == "generate"]
    assert [(c.renderer, c.ground_truth, c.supersample, c.out) for c in gens] == [
        ("hybrid", None, 2, None),
        ("ground_truth", sample_dir.resolve(), 1, ws.dataset_dir("grasp_banana_ground_truth"))]  # fmt: skip
    evals = {c.name: c for name, c in calls if name == "eval_policy"}
    assert {"grasp_banana_ground_truth_150-ground_truth", "grasp_banana_ground_truth_150-hybrid"} <= set(evals)
    assert result["policies"][-1]["kind"] == "oracle"
    md = result["tables"].split("Oracle")[1]
    assert "| the reconstruction's (the method) | 60.0 % [46-72] (30/50) | 60.0 % [46-72] (30/50) |" in md
    assert "| the ground truth's own (oracle) | 72.0 % [58-83] (36/50) | 72.0 % [58-83] (36/50) |" in md
    assert Sim2RealConfig(sample=sample_dir).oracle_demos == 0
    with pytest.raises(M2MError, match="oracle_demos .* must be one of demos"):
        Sim2RealConfig(sample=sample_dir, oracle_demos=100).validate()


def test_the_main_policies_are_their_training_seeds_as_one(tmp_path, sample_dir, monkeypatch):
    """By default the bench runs the recipe the README measured: 300 demos of the expert with `--tie 2 --look 0.5`,
    drawn at frame size, four training seeds of 4,000 steps each deployed as one, the first seed alone beside them;
    the data-scale curve and the ablation train one seed."""
    from mirage2matter.bench import sim2real

    scores = {"grasp_banana_tie_2_look_0_5_300_x4": 43, "grasp_banana_tie_2_look_0_5_300": 40}
    ws, calls = recorded_bench(tmp_path, monkeypatch, lambda cfg: _e(scores.get(cfg.name.split("-")[0], 30)))
    cfg = Sim2RealConfig(sample=sample_dir)
    assert (cfg.task, cfg.seeds, cfg.steps, cfg.supersample, cfg.parallel) == (
        "grasp banana --tie 2 --look 0.5", 4, 4000, 1, 2)  # fmt: skip
    cfg.parallel = 1  # side by side: the test below
    result = sim2real.run_sim2real(ws, cfg, log=lambda m: None)
    grasp = [c for name, c in calls if name == "generate" and c.task == (cfg.task,)]
    assert [(c.episodes, c.supersample, c.objects) for c in grasp] == [(300, 1, "gaussians"), (150, 1, "meshes")]
    trains = [c for name, c in calls if name == "train_policy"]
    main = [c for c in trains if c.episodes == 300]
    slug = "grasp_banana_tie_2_look_0_5"
    assert [(c.name, c.seed, c.steps) for c in main] == [
        (f"{slug}_300", 0, 4000), (f"{slug}_300_s1", 1, 4000), (f"{slug}_300_s2", 2, 4000), (f"{slug}_300_s3", 3, 4000)
    ]  # fmt: skip
    assert sorted(c.seed for c in trains if c.episodes != 300 and c.datasets == (slug,)) == [0, 0]  # curve: 50, 150
    evals = {c.name: c for name, c in calls if name == "eval_policy"}
    ens = evals[f"{slug}_300_x4-ground_truth"]
    assert ens.policy == ",".join(c.name for c in main) and ens.task == cfg.task
    assert evals[f"{slug}_300_x4-hybrid"].policy == ens.policy
    assert evals[f"{slug}_300-ground_truth"].policy == f"{slug}_300"  # the first seed alone
    assert evals["press_button_150_x4-ground_truth"].policy.count(",") == 3
    row = result["policies"][0]
    assert (row["seeds"], row["train_minutes"], row["train_steps"]) == (4, 4.0, [4000] * 4)
    md = result["tables"]
    assert "| 4 training seeds as one | 86.0 % [74-93] (43/50) |" in md
    assert "| 300 | 80.0 % [67-89] (40/50) |" in md.split("Data scale")[1]
    assert "without splat supersampling" in md
    # the seed-0 trainings done earlier (main 300, the curve's 50 and 150, press, ablation: 5 x 60 s) count
    assert 5.0 <= result["minutes"]["training"] < 5.2


def test_the_seeds_train_side_by_side_in_one_workspace(tmp_path, capfd):
    """The bench's seeds train in child processes at once (the workspace lock lets policy stages run side by
    side); each lands as a finished policy with its own record, and a rerun finds them done."""
    import json

    from fixtures.policy_datasets import build_dataset, spec_for, tiny_config
    from mirage2matter.bench import sim2real
    from mirage2matter.stages import train_policy
    from mirage2matter.workspace import Workspace

    ws = Workspace(tmp_path / "ws")
    build_dataset(ws.datasets_dir / "demos", spec_for(), length=12)
    base = {f: getattr(tiny_config(steps=4), f)
            for f in ("image_size", "chunk", "batch_size", "warmup_steps", "steps", "widths", "keypoints", "hidden",
                      "val_fraction")}  # fmt: skip
    cfgs = [train_policy.Config(datasets=("demos",), name=f"p{k}", seed=k, **base) for k in range(2)]
    done = sim2real._side_by_side(ws, "train_policy", cfgs, 2, log=lambda m: None)
    assert [(s["steps"], skipped) for s, _, skipped in done] == [(4, False), (4, False)]
    err = capfd.readouterr().err
    assert "[p0] " in err and "[p1] " in err  # each child's lines carry its policy's name
    records = json.loads(ws.record_file.read_text())
    assert {"train_policy/p0", "train_policy/p1"} <= set(records)
    assert all((ws.policy_dir(f"p{k}") / "policy.pt").is_file() for k in range(2))
    assert not (ws.root / ".m2m").exists()
    again = sim2real._side_by_side(ws, "train_policy", cfgs, 2, log=lambda m: None)
    assert [skipped for _, _, skipped in again] == [True, True]
    assert "[p0] " not in capfd.readouterr().err  # found done here: no child started

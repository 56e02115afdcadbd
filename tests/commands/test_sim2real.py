"""bench sim2real's report: the paper's tables from the policies' evaluations, and its settings' checks."""

from __future__ import annotations

import pytest

from mirage2matter.commands.sim2real import Sim2RealConfig, markdown_tables
from mirage2matter.errors import M2MError


def _e(k: int, n: int = 50) -> dict:
    from mirage2matter.evaluation import wilson_interval

    return {"successes": k, "episodes": n, "success_rate": k / n, "wilson95": list(wilson_interval(k, n)),
            "mean_steps": 60.0}  # fmt: skip


def test_tables_hold_every_policy_with_its_interval(sample_dir):
    cfg = Sim2RealConfig(sample=sample_dir)
    rows = [
        {"kind": "main", "task": "grasp banana", "demos": 300, "ground_truth": _e(40), "hybrid": _e(45)},
        {"kind": "main", "task": "press button", "demos": 150, "ground_truth": _e(41), "hybrid": _e(49)},
        {"kind": "data_scale", "task": "grasp banana", "demos": 50, "ground_truth": _e(20)},
        {"kind": "data_scale", "task": "grasp banana", "demos": 150, "ground_truth": _e(35)},
        {"kind": "ablation", "task": "grasp banana", "demos": 150, "ground_truth": _e(30), "hybrid": _e(44)},
    ]
    md = markdown_tables({"policies": rows, "minutes": {"generation": 30.0, "training": 50.0, "evaluation": 60.0}},
                         cfg)  # fmt: skip
    assert "| grasp banana | 300 | 80.0 % [67-89] (40/50) | 90.0 % [79-96] (45/50) |" in md
    assert "| 3DGS (the method) | 70.0 % [56-81] (35/50) | - |" in md  # the Gaussian twin at 150 demos
    # and the ablation's policy in its own world: whether it learnt the task at all, beside the gap
    assert "| mesh only (vertex-coloured) | 60.0 % [46-72] (30/50) | 88.0 % [76-94] (44/50) |" in md
    scale = md.split("Data scale")[1]
    assert scale.index("| 50 |") < scale.index("| 150 |") < scale.index("| 300 |")
    assert "generation 30.0 min, training 50.0 min, evaluation 60.0 min" in md


def test_settings_are_checked(tmp_path, sample_dir):
    with pytest.raises(M2MError, match="no ground_truth.json"):
        Sim2RealConfig(sample=tmp_path).validate()
    with pytest.raises(M2MError, match="ablation_demos .* must be one of demos"):
        Sim2RealConfig(sample=sample_dir, ablation_demos=100).validate()

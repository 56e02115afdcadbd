"""`m2m sample make --robot ur5e`: the second robot holds the hand-eye board; the sample names it (joints file,
m2m.yaml, ground truth) and hand-eye calibration from its joints recovers the head camera (slow: ~1-2 minutes)."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from mirage2matter.geometry.rotation import rotation_angle


@pytest.mark.slow
def test_a_short_sample_with_the_ur5e(tmp_path):
    from mirage2matter.calib.board import load_target
    from mirage2matter.calib.handeye import calibrate_from_files
    from mirage2matter.geometry.camera import load_intrinsics
    from mirage2matter.inputs import read_yaml
    from mirage2matter.robots import get_robot
    from mirage2matter.sample.make import SampleConfig, make_sample

    out = tmp_path / "sample"
    config = replace(SampleConfig.short(seed=1), robot="ur5e")
    gt = make_sample(out, config, log=lambda _m: None)
    spec = get_robot("ur5e")
    joints = json.loads((out / "handeye" / "joints.json").read_text())
    assert joints["robot"] == "ur5e" and joints["link"] == spec.ee_link
    assert all(len(v["joints"]) == spec.n_dofs for v in joints["views"]) and len(joints["views"]) == 6
    settings = read_yaml(out / "m2m.yaml")
    assert settings["robot"] == "ur5e" and "robot" not in settings.get("align", {})  # the pipeline's, written once
    assert gt["handeye"]["robot"] == gt["config"]["robot"] == "ur5e"
    cam = load_intrinsics(out / "ground_truth.json", keys=("head_camera",))
    _, res = calibrate_from_files(out / "handeye" / "images", out / "handeye" / "joints.json",
                                  load_target(out / "handeye" / "board.json"), cam, mount="head")  # fmt: skip
    T, T_gt = np.asarray(res["T_base_headcam"]), np.asarray(gt["head_camera"]["T_base_headcam"])
    assert np.linalg.norm(T[:3, 3] - T_gt[:3, 3]) < 0.002
    assert np.degrees(rotation_angle(T[:3, :3].T @ T_gt[:3, :3])) < 0.2

"""Hand-eye on a public, real capture (tests/fixtures/public_handeye.py: a Franka Panda with a RealSense on its
wrist, 12 ChArUco views, the authors' own calibration to compare with). Skipped where the data is absent."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fixtures.public_handeye import FRANKA_HANDEYE, SOURCE, convert_franka_handeye, franka_handeye_present
from mirage2matter.calib.handeye import HandEyeError
from mirage2matter.cli import main
from mirage2matter.geometry.rotation import rotation_angle

pytestmark = pytest.mark.skipif(
    not franka_handeye_present(),
    reason=f"public hand-eye data not present: {FRANKA_HANDEYE} ({SOURCE}; or set M2M_FRANKA_HANDEYE)",
)

# panda.xml's "hand" link is the flange side of the gripper; Franka's default EE frame sits 103.4 mm further along
# its z, unrotated (measured: FK of the logged joints vs the logged O_T_EE, 0.000 mm / 0.0 deg otherwise).
T_HAND_EE = np.eye(4)
T_HAND_EE[2, 3] = 0.1034


def _errors(T: np.ndarray, T_ref: np.ndarray) -> tuple[float, float]:
    return (float(np.degrees(rotation_angle(T[:3, :3].T @ T_ref[:3, :3]))),
            float(1000 * np.linalg.norm(T[:3, 3] - T_ref[:3, 3])))  # fmt: skip


@pytest.fixture(scope="module")
def franka(tmp_path_factory):
    return convert_franka_handeye(tmp_path_factory.mktemp("franka_handeye"))


def _calibrate(data, ws, poses="joints.json", *extra) -> dict:
    root = data["root"]
    assert main(["calibrate-handeye", "-w", str(ws), "--mount", "wrist", "--images", str(root / "images"),
                 "--joints", str(root / poses), "--board", str(root / "board.json"), "--intrinsics",
                 str(root / "intrinsics.json"), *extra]) == 0  # fmt: skip
    return json.loads((ws / "calib" / "handeye.json").read_text())


def test_defaults_match_the_authors_calibration(franka, tmp_path):
    out = _calibrate(franka, tmp_path / "joints")
    X = np.asarray(out["T_hand_wristcam"])
    # the authors' result (another solver on their own detections) within 1.5 mm / 0.15 deg; measured 1.11 mm /
    # 0.043 deg. The report of the former default on this capture: 18.1 mm / 2.51 deg.
    deg, mm = _errors(X, T_HAND_EE @ franka["T_EE_cam"])
    assert deg <= 0.15 and mm <= 1.5, (deg, mm)
    assert out["lens_corrected"] and len(out["per_view"]) == 12
    # the quality figure is the held-out corner error: a few px on a real arm (measured 3.93 px median)
    assert 1.0 < out["loo_px_median"] < 6.0
    # the end-effector poses the arm logged give the same mount, in the EE frame
    ee = _calibrate(franka, tmp_path / "ee", "ee_poses.json")
    deg, mm = _errors(T_HAND_EE @ np.asarray(ee["T_EE_wristcam"]), X)
    assert deg < 0.01 and mm < 0.1, (deg, mm)


def test_taking_the_arm_as_exact_is_worse_on_real_poses(franka, tmp_path):
    # the refinement that trusts the robot's poses slides along the nearly flat direction (measured 18.8 mm /
    # 2.58 deg from the authors'), which is why it is not a default
    out = _calibrate(franka, tmp_path / "exact", "joints.json", "--refine", "exact")
    deg, mm = _errors(np.asarray(out["T_hand_wristcam"]), T_HAND_EE @ franka["T_EE_cam"])
    assert mm > 5.0 and deg > 1.0, (deg, mm)


def test_the_wrong_mount_is_refused(franka, tmp_path):
    root = franka["root"]
    with pytest.raises(HandEyeError, match="wrist"):
        main(["--debug", "calibrate-handeye", "-w", str(tmp_path / "ws"), "--mount", "head", "--images",
              str(root / "images"), "--joints", str(root / "joints.json"), "--board", str(root / "board.json"),
              "--intrinsics", str(root / "intrinsics.json")])  # fmt: skip
    assert not (tmp_path / "ws" / "calib" / "handeye.json").exists()

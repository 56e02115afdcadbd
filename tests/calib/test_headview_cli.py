"""`m2m head-view` on a workspace whose scene is a splatted board at the sample's board pose."""

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from mirage2matter.calib.board import BoardSpec
from mirage2matter.cli import main
from mirage2matter.gaussians.ply import write_ply
from mirage2matter.stages.pipeline import PipelineConfig

sys.path.insert(0, str(Path(__file__).parent))
from test_headview import board_gaussians  # noqa: E402

from fixtures import SAMPLE


def write_calibration(ws: Path, head: dict, board: BoardSpec, T_base_board: np.ndarray) -> None:
    """calib/ as the hand-eye and alignment stages leave it: the head camera (handeye.json) and the board's pose."""
    (ws / "calib").mkdir()
    (ws / "calib" / "handeye.json").write_text(json.dumps({
        "mount": "head", "T_base_headcam": head["T_base_headcam"], "K": head["K"],
        "width": head["width"], "height": head["height"]}))  # fmt: skip
    (ws / "calib" / "sim3_sfm_to_base.json").write_text(
        json.dumps({"board": board.to_json(), "T_base_board": T_base_board.tolist()})
    )


@pytest.mark.skipif(not (SAMPLE / "ground_truth.json").is_file(), reason="samples/tabletop not built")
def test_head_view_cli_writes_the_comparison_and_names_missing_stages(tmp_path, capsys):
    gt = json.loads((SAMPLE / "ground_truth.json").read_text())
    ws = tmp_path / "ws"
    assert main(["head-view", "-w", str(ws)]) == 2
    assert "run `m2m train-scene" in capsys.readouterr().err

    board = BoardSpec.from_json(gt["board"]["spec"])
    T_base_board = np.asarray(gt["board"]["T_base_board"])
    (ws / "scene").mkdir(parents=True)
    write_ply(ws / "scene" / "gaussians.ply", board_gaussians(board, T_base_board))
    write_calibration(ws, gt["head_camera"], board, T_base_board)
    assert main(["head-view", "-w", str(ws), "--photo", str(SAMPLE / "head_view.png"), "--backend", "cpu"]) == 0
    out = capsys.readouterr().out
    assert "px (median, 24) from the board's known pose" in out  # all of it: the head camera sees the whole board
    report = json.loads((ws / "calib" / "head_view.json").read_text())
    assert report["corners_vs_photo_px"]["median"] < 1.5 and report["psnr"] is not None
    assert (ws / "calib" / "head_view.png").is_file()


@pytest.mark.skipif(not (SAMPLE / "ground_truth.json").is_file(), reason="samples/tabletop not built")
def test_head_view_cli_draws_the_robots_gaussians_at_the_photo_joints(tmp_path, capsys):
    """With scene/robot/ (the robot's Gaussians train-scene fits) the check draws the robot at the capture joints
    (head_photo_joints: another state, the pipeline's: m2m.yaml holds it once, train-scene reads it too), says so,
    and its robot pixels match the photo; a head_photo_joints in degrees or of the wrong length is refused naming the
    setting, nothing written."""
    from PIL import Image
    from test_headview import photo_coloured_robot

    from mirage2matter.geometry.camera import Camera

    gt = json.loads((SAMPLE / "ground_truth.json").read_text())
    board = BoardSpec.from_json(gt["board"]["spec"])
    T_base_board = np.asarray(gt["board"]["T_base_board"])
    head = gt["head_camera"]
    ws = tmp_path / "ws"
    (ws / "scene" / "robot").mkdir(parents=True)
    write_ply(ws / "scene" / "gaussians.ply", board_gaussians(board, T_base_board, pps=20))
    write_calibration(ws, head, board, T_base_board)
    photo = SAMPLE / "head_view.png"
    run = ["head-view", "-w", str(ws), "--photo", str(photo), "--backend", "cpu"]
    assert main(run) == 0  # no robot Gaussians: the scene alone, as before, and the line says so
    assert "the robot not drawn: the workspace has no robot Gaussians" in capsys.readouterr().out
    alone = json.loads((ws / "calib" / "head_view.json").read_text())
    assert "robot_drawn" not in alone

    cam = Camera(head["K"], head["T_base_headcam"], head["width"], head["height"], "head")
    q = gt["robot"]["capture_joints"]
    robot, _ = photo_coloured_robot(cam, np.asarray(Image.open(photo).convert("RGB")), q)
    for link, g in robot.items():
        write_ply(ws / "scene" / "robot" / f"{link}.ply", g)
    (ws / "scene" / "robot" / "robot.json").write_text(json.dumps({
        "robot": "panda", "capture_joints": q, "links": {link: f"{link}.ply" for link in robot}}))  # fmt: skip
    assert main(run) == 0
    out = capsys.readouterr().out
    assert "the robot drawn from its Gaussians (scene/robot/) at the capture joints" in out and "robot's pixels" in out
    drawn = json.loads((ws / "calib" / "head_view.json").read_text())
    assert drawn["robot_drawn"] and drawn["psnr"] > alone["psnr"] + 0.5 and drawn["psnr_robot"] > 20.0

    away = [str(v) for v in np.asarray(q[:7]) + [0.4, 0, 0, 0, 0, 0, 0]]
    assert main([*run, "--head-photo-joints", *away]) == 0
    assert "at head_photo_joints" in capsys.readouterr().out
    saved = PipelineConfig.load(ws / "m2m.yaml")
    assert saved.head_photo_joints == saved.scene.head_photo_joints == saved.head_view.head_photo_joints == \
        [float(v) for v in away]  # fmt: skip
    assert "\nhead_photo_joints: [" in (ws / "m2m.yaml").read_text()  # once, at the top
    assert json.loads((ws / "calib" / "head_view.json").read_text())["psnr_robot"] < drawn["psnr_robot"] - 5.0

    before = (ws / "calib" / "head_view.json").read_bytes()
    degrees = [str(round(float(np.degrees(v)), 1)) for v in q[:7]]
    assert main([*run, "--head-photo-joints", *degrees]) == 2
    err = capsys.readouterr().err
    assert "head_photo_joints" in err and "reads as degrees" in err
    assert main([*run, "--head-photo-joints", "0.1", "0.2"]) == 2
    assert "head_photo_joints: 2 values given; panda has 7 arm joints" in capsys.readouterr().err
    assert (ws / "calib" / "head_view.json").read_bytes() == before

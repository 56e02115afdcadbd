"""`m2m head-view` on a workspace whose scene is a splatted board at the sample's board pose."""

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from mirage2matter.calib.board import BoardSpec
from mirage2matter.cli import main
from mirage2matter.gaussians.ply import write_ply

sys.path.insert(0, str(Path(__file__).parent))
from test_headview import board_gaussians  # noqa: E402

from fixtures import SAMPLE


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
    head = gt["head_camera"]
    (ws / "calib").mkdir()
    (ws / "calib" / "handeye.json").write_text(json.dumps({
        "mount": "head", "T_base_headcam": head["T_base_headcam"], "K": head["K"],
        "width": head["width"], "height": head["height"]}))  # fmt: skip
    (ws / "calib" / "sim3_sfm_to_base.json").write_text(
        json.dumps({"board": board.to_json(), "T_base_board": T_base_board.tolist()})
    )
    assert main(["head-view", "-w", str(ws), "--photo", str(SAMPLE / "head_view.png"), "--backend", "cpu"]) == 0
    out = capsys.readouterr().out
    assert "px (median, 24) from the board's known pose" in out  # all of it: the head camera sees the whole board
    report = json.loads((ws / "calib" / "head_view.json").read_text())
    assert report["corners_vs_photo_px"]["median"] < 1.5 and report["psnr"] is not None
    assert (ws / "calib" / "head_view.png").is_file()

"""Calibration targets labs use: ChArUco, one ArUco marker, an AprilTag, an ArUco grid: geometry, detection
accuracy on a known homography, their JSON and `m2m board`."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from mirage2matter.calib.board import (
    BoardError,
    BoardSpec,
    GridSpec,
    MarkerSpec,
    board_frame_to_board_image,
    load_target,
    target_from_json,
)
from mirage2matter.cli import main

TARGETS = {
    "charuco": BoardSpec(),
    "aruco": MarkerSpec(0.186, 7, "DICT_6X6_250"),
    "apriltag": MarkerSpec(0.15, 3, "DICT_APRILTAG_36h11", "apriltag"),
    "aruco_grid": GridSpec(4, 5, 0.04, 0.01, "DICT_4X4_50"),
}
# an oblique view (shear and perspective) and a plain shift
HOMOGRAPHIES = [np.array([[0.8, 0.15, 60], [-0.1, 0.9, 40], [3e-4, 2e-4, 1.0]]), np.array([[1, 0, 50], [0, 1, 30],
                                                                                            [0, 0, 1.0]])]  # fmt: skip


def _corner_errors(spec, H: np.ndarray) -> np.ndarray:
    pps = 100
    img = spec.render_image(pps, 0.5)
    seen = cv2.warpPerspective(img, H, (img.shape[1] + 200, img.shape[0] + 200), flags=cv2.INTER_AREA,
                               borderValue=255)  # fmt: skip
    seen = cv2.GaussianBlur(seen, (0, 0), 1.0)  # defocus
    ids, uv = spec.detect(seen)
    px = board_frame_to_board_image(spec.points_board(ids), spec, pps, 0.5) - 0.5  # OpenCV's pixel centres
    q = np.c_[px, np.ones(len(px))] @ H.T
    return np.linalg.norm(q[:, :2] / q[:, 2:] - uv, axis=1)


@pytest.mark.parametrize("kind", TARGETS)
def test_each_target_is_found_where_it_is(kind):
    spec = TARGETS[kind]
    for H in HOMOGRAPHIES:
        err = _corner_errors(spec, H)
        n = {"charuco": 24, "aruco": 4, "apriltag": 4, "aruco_grid": 80}[kind]
        assert len(err) == n
        # single markers: their edges re-measured (OpenCV's own corners sit 0.2-0.7 px inside)
        assert np.median(err) < 0.12 and err.max() < 0.5, (kind, np.median(err), err.max())


@pytest.mark.parametrize("kind", TARGETS)
def test_targets_round_trip_through_json_and_m2m_board(kind, tmp_path, capsys):
    spec = TARGETS[kind]
    assert target_from_json(spec.to_json()) == spec and spec.kind == kind
    w, h = spec.size
    pts = spec.points_board()
    assert pts[:, 0].min() >= 0 and pts[:, 0].max() <= w + 1e-12 and pts[:, 1].max() <= h + 1e-12
    args = ["board", "--type", kind, "--out", str(tmp_path / "t.pdf")]
    if kind == "aruco":
        args += ["--size", "0.186", "--id", "7"]
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "Print at 100%" in out and (tmp_path / "t.pdf").is_file() and (tmp_path / "t.png").is_file()
    printed = load_target(tmp_path / "t.json")
    assert printed.kind == kind and printed.describe() in out


def test_a_charuco_file_without_a_type_still_loads(tmp_path):
    path = tmp_path / "board.json"
    path.write_text(json.dumps(BoardSpec().to_json()))
    assert "type" not in json.loads(path.read_text()) and load_target(path) == BoardSpec()


@pytest.mark.parametrize(
    ("data", "match"),
    [
        ({"type": "aruco", "size": 0.15, "id": 600, "dictionary": "DICT_6X6_250"}, "ids 0..249"),
        ({"type": "apriltag", "size": 0.15, "dictionary": "DICT_4X4_50"}, "DICT_APRILTAG"),
        ({"type": "aruco", "size": 0.15, "dictionary": "DICT_APRILTAG_36h11"}, "not AprilTag"),
        ({"type": "aruco", "id": 3}, "needs its size"),
        ({"type": "aruco", "size": -1}, "> 0"),
        ({"type": "qr", "size": 0.1}, "not one of"),
        ({"type": "aruco_grid", "markers_x": 1, "markers_y": 1}, "at least 2 markers"),
        ({"type": "aruco", "size": 0.1, "colour": "red"}, "unknown keys"),
    ],
)
def test_bad_target_specs_are_named(tmp_path, data, match):
    path = tmp_path / "target.json"
    path.write_text(json.dumps(data))
    with pytest.raises(BoardError, match=match) as e:
        load_target(path)
    assert str(path) in str(e.value)

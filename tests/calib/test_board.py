import json

import cv2
import numpy as np
import pytest

from mirage2matter.calib.board import (
    BoardSpec,
    MarkerSpec,
    board_frame_to_board_image,
    board_image_to_board_frame,
    margin_pixels,
    on_target,
)


def test_json_round_trip_and_file(tmp_path):
    spec = BoardSpec(squares_x=6, squares_y=9, square=0.03, marker=0.022, dictionary="DICT_4X4_50")
    assert BoardSpec.from_json(json.loads(json.dumps(spec.to_json()))) == spec
    path = tmp_path / "calib" / "board.json"
    spec.save(path)
    assert BoardSpec.load(path) == spec
    assert [p.name for p in path.parent.iterdir()] == ["board.json"]  # no temporary left behind
    assert BoardSpec.load(path).to_json() == json.loads(path.read_text())


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"marker": 0.04}, "must be smaller than BoardSpec.square"),
        ({"marker": 0.05}, "must be smaller than BoardSpec.square"),
        ({"square": -0.04}, "BoardSpec.square must be finite and > 0"),
        ({"marker": 0.0}, "BoardSpec.marker must be finite and > 0"),
        ({"square": float("nan")}, "BoardSpec.square must be finite"),
        ({"squares_x": 1}, "BoardSpec.squares_x must be an integer >= 2"),
        ({"squares_y": 7.0}, "BoardSpec.squares_y must be an integer >= 2"),
        ({"dictionary": "DICT_5X5_99"}, "not a cv2.aruco predefined dictionary"),
        ({"dictionary": "CharucoBoard"}, "not a cv2.aruco predefined dictionary"),
        ({"squares_x": 12, "squares_y": 12, "dictionary": "DICT_4X4_50"}, "needs 72 markers"),
    ],
)
def test_invalid_specs_are_rejected(kwargs, message):
    with pytest.raises(ValueError, match=message):
        BoardSpec(**kwargs)


def test_bad_json_is_rejected(tmp_path):
    with pytest.raises(ValueError, match="lacks"):
        BoardSpec.from_json({"squares_x": 5})
    with pytest.raises(ValueError, match="unknown keys"):
        BoardSpec.from_json({**BoardSpec().to_json(), "legacy": True})
    bad = tmp_path / "board.json"
    bad.write_text("{not json")
    with pytest.raises(ValueError, match="board.json is not valid JSON"):
        BoardSpec.load(bad)


def test_geometry_matches_opencv():
    spec = BoardSpec()
    assert spec.size == pytest.approx((0.20, 0.28))
    assert spec.n_corners == 24
    pts = spec.corner_points_board()
    assert pts.shape == (24, 3)
    np.testing.assert_allclose(pts, spec.cv_board().getChessboardCorners(), atol=1e-7)
    np.testing.assert_allclose(pts[0], [0.04, 0.04, 0.0])
    np.testing.assert_allclose(pts[1], [0.08, 0.04, 0.0])  # x runs fastest


@pytest.mark.parametrize(
    "spec, pps, margin",
    [(BoardSpec(), 100, 0.5), (BoardSpec(), 60, 0.5), (BoardSpec(7, 5, 0.03, 0.021, "DICT_4X4_50"), 80, 1.0)],
)
def test_rendered_image_is_detected_at_the_mapped_corners(spec, pps, margin):
    img = spec.render_image(px_per_square=pps, margin_squares=margin)
    m = margin_pixels(pps, margin)
    assert img.dtype == np.uint8
    assert img.shape == (spec.squares_y * pps + 2 * m, spec.squares_x * pps + 2 * m)
    assert (img[:m] == 255).all() and (img[:, -m:] == 255).all()  # white margin
    assert img[m, m] == 0  # the top-left square is black

    corners, ids, _, _ = cv2.aruco.CharucoDetector(spec.cv_board()).detectBoard(img)
    assert ids is not None and len(ids) == spec.n_corners
    detected = corners.reshape(-1, 2) + 0.5  # OpenCV pixel centres at integers -> ours at +0.5
    expected = board_frame_to_board_image(spec.corner_points_board()[ids.ravel()], spec, pps, margin)
    assert np.abs(detected - expected).max() <= 0.5
    np.testing.assert_allclose(
        board_image_to_board_frame(expected, spec, pps, margin), spec.corner_points_board()[ids.ravel()], atol=1e-12
    )


def test_image_square_edges_fall_on_pixel_boundaries():
    spec, pps = BoardSpec(), 50
    img = spec.render_image(px_per_square=pps, margin_squares=0.5)
    for k, (x, y, _) in enumerate(spec.corner_points_board()):
        col, row = board_frame_to_board_image(np.array([x, y]), spec, pps, 0.5)
        c, r = int(col), int(row)
        assert (c, r) == (col, row)
        # Around every inner corner the four touching pixels form a checker: diagonal pairs agree.
        tl, tr, bl, br = img[r - 1, c - 1], img[r - 1, c], img[r, c - 1], img[r, c]
        assert tl == br and tr == bl and tl != tr, f"corner {k} at ({col}, {row})"


def test_margin_must_be_whole_pixels():
    with pytest.raises(ValueError, match="whole number of pixels"):
        BoardSpec().render_image(px_per_square=25, margin_squares=0.5)
    with pytest.raises(ValueError, match="px_per_square must be an integer"):
        BoardSpec().render_image(px_per_square=50.0)


def test_printable_board_is_true_scale_and_detectable(tmp_path):
    import re

    from PIL import Image

    from mirage2matter.calib.board import write_printable
    from mirage2matter.cli import main

    assert main(["board", "--out", str(tmp_path / "b.pdf"), "--squares", "5x7", "--square", "0.04"]) == 0
    pdf = (tmp_path / "b.pdf").read_bytes()
    box = [float(v) for v in re.search(rb"/MediaBox\s*\[\s*([\d.\s]+)\]", pdf).group(1).split()]
    width_mm, height_mm = (box[2] - box[0]) / 72 * 25.4, (box[3] - box[1]) / 72 * 25.4
    assert abs(width_mm - 240.0) < 0.5 and abs(height_mm - 320.0) < 0.5  # (5+1) x (7+1) squares of 40 mm
    spec = BoardSpec.load(tmp_path / "b.json")
    assert (spec.squares_x, spec.squares_y, spec.square, spec.dictionary) == (5, 7, 0.04, "DICT_5X5_100")
    png = np.asarray(Image.open(tmp_path / "b.png").convert("L"))
    corners, ids, _, _ = cv2.aruco.CharucoDetector(spec.cv_board()).detectBoard(png)
    assert ids is not None and len(ids) == spec.n_corners
    with pytest.raises(ValueError, match=".pdf"):
        write_printable(spec, tmp_path / "b.png")


@pytest.mark.parametrize("target", [BoardSpec(square=0.055, marker=0.042, dictionary="DICT_4X4_50"), MarkerSpec(0.18)],
                         ids=["charuco", "aruco"])  # fmt: skip
def test_points_on_the_target_sheet_are_found_and_the_table_beside_it_is_not(target):
    """A target lying beside the robot's base (board z into the table, as align-scene records it): points on its
    sheet, its white margin included, and just above it are the target's; points 15 cm beside it or 10 cm above not."""
    T_base_target = np.array([[0.0, 1, 0, -0.02], [1, 0, 0, -0.44], [0, 0, -1, 0.0005], [0, 0, 0, 1]])
    w, h = target.size
    rng = np.random.default_rng(0)
    local = np.c_[rng.uniform(-0.2 * target.feature_size, w + 0.2 * target.feature_size, 200),
                  rng.uniform(-0.2 * target.feature_size, h + 0.2 * target.feature_size, 200),
                  rng.uniform(-0.02, 0.002, 200)]  # fmt: skip  # z into the table: up to 2 cm above it
    to_base = lambda p: p @ T_base_target[:3, :3].T + T_base_target[:3, 3]
    assert on_target(to_base(local), target, T_base_target).all()
    beside = local + [w + 1.5 * target.feature_size + 0.15, 0, 0]
    above = local - [0, 0, 0.1]
    assert not on_target(to_base(np.r_[beside, above]), target, T_base_target).any()

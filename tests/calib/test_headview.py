"""The head-camera check: a splatted ChArUco board at its known pose, seen through the head camera."""

import json

import numpy as np
import pytest
import torch
from PIL import Image

from fixtures import SAMPLE
from mirage2matter.calib.board import BoardSpec, board_image_to_board_frame
from mirage2matter.calib.headview import check_head_view
from mirage2matter.gaussians.model import Gaussians
from mirage2matter.gaussians.sh import rgb_to_sh_dc
from mirage2matter.geometry.camera import Camera


def board_gaussians(board: BoardSpec, T_base_board: np.ndarray, pps: int = 60) -> Gaussians:
    """The printed board as flat Gaussians, one per texel (pps texels per square), at its pose."""
    img = board.render_image(px_per_square=pps, margin_squares=0.5).astype(np.float32) / 255
    rows, cols = np.mgrid[0 : img.shape[0], 0 : img.shape[1]]
    pix = np.stack([cols.ravel() + 0.5, rows.ravel() + 0.5], axis=-1)
    p_board = board_image_to_board_frame(pix, board, px_per_square=pps, margin_squares=0.5)
    means = p_board @ T_base_board[:3, :3].T + T_base_board[:3, 3]
    n = len(means)
    texel = board.square / pps
    R = T_base_board[:3, :3]
    # flat discs in the board plane: quaternion of the board rotation, tiny scale along its normal
    from mirage2matter.geometry.rotation import matrix_to_quat

    quats = torch.as_tensor(np.tile(matrix_to_quat(R), (n, 1)), dtype=torch.float32)
    log_scales = torch.log(torch.tensor([[0.5 * texel, 0.5 * texel, 1e-4]])).repeat(n, 1)
    colors = torch.as_tensor(np.repeat(img.reshape(-1, 1), 3, axis=1))
    return Gaussians(
        torch.as_tensor(means, dtype=torch.float32), quats, log_scales, torch.full((n,), 6.0),
        rgb_to_sh_dc(colors)[:, None, :],
    )  # fmt: skip


@pytest.mark.skipif(not (SAMPLE / "ground_truth.json").is_file(), reason="samples/tabletop not built")
def test_head_view_check_sees_the_board_where_it_is_and_flags_a_wrong_mount():
    gt = json.loads((SAMPLE / "ground_truth.json").read_text())
    board = BoardSpec.from_json(gt["board"]["spec"])
    T_base_board = np.asarray(gt["board"]["T_base_board"])
    head = gt["head_camera"]
    cam = Camera(head["K"], head["T_base_headcam"], head["width"], head["height"], "head")
    photo = np.asarray(Image.open(SAMPLE / head["image"]).convert("RGB"))
    g = board_gaussians(board, T_base_board)

    good = check_head_view(g, cam, photo, board, T_base_board, backend="cpu")
    # ~0.9 px, not 0: opaque coplanar splats smaller than a pixel (plus gsplat's 0.3 px^2 dilation)
    # composite front to back, so nearer texels bleed over farther ones; a trained scene has no such grid
    assert good.corners_vs_known_px["n"] >= 12 and good.corners_vs_known_px["median"] < 1.5
    # the robot's forearm hides most of the board in the head photo: 9 of its 24 corners are found there
    assert good.corners_vs_photo_px["n"] >= 8 and good.corners_vs_photo_px["median"] < 1.5
    assert good.psnr is not None and np.isfinite(good.psnr)

    moved = cam.T_world_cam.copy()
    moved[:3, 3] += [0.01, 0.0, 0.0]  # a 1 cm error in the hand-eye mount
    bad = check_head_view(g, Camera(cam.K, moved, cam.width, cam.height), photo, board, T_base_board, backend="cpu")
    assert bad.corners_vs_photo_px["median"] > 3.0
    assert bad.corners_vs_known_px["median"] < 1.5  # consistent with its own (wrong) pose, as it should be

"""The head-camera check: a splatted ChArUco board at its known pose, seen through the head camera."""

import json

import numpy as np
import pytest
import torch
from PIL import Image

from fixtures import SAMPLE
from mirage2matter.calib.board import BoardSpec, board_image_to_board_frame
from mirage2matter.calib.robot_view import grow_mask, robot_silhouette
from mirage2matter.gaussians.model import Gaussians
from mirage2matter.gaussians.sh import rgb_to_sh_dc
from mirage2matter.geometry.camera import Camera
from mirage2matter.render.head_view import check_head_view


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


def head_sample() -> tuple[dict, BoardSpec, np.ndarray, Camera, np.ndarray]:
    """The sample's ground truth (gt), its board and the board's pose T_base_board, the head camera and its photo."""
    gt = json.loads((SAMPLE / "ground_truth.json").read_text())
    head = gt["head_camera"]
    cam = Camera(head["K"], head["T_base_headcam"], head["width"], head["height"], "head")
    photo = np.asarray(Image.open(SAMPLE / head["image"]).convert("RGB"))
    return gt, BoardSpec.from_json(gt["board"]["spec"]), np.asarray(gt["board"]["T_base_board"]), cam, photo


@pytest.mark.skipif(not (SAMPLE / "ground_truth.json").is_file(), reason="samples/tabletop not built")
def test_head_view_check_sees_the_board_where_it_is_and_flags_a_wrong_mount():
    _, board, T_base_board, cam, photo = head_sample()
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


def photo_coloured_robot(cam: Camera, photo: np.ndarray, q, spacing: float = 0.008):
    """(the robot's Gaussians {link: link frame} coloured by the head photo where each lands, its links at ``q``):
    a robot whose look is the photo's, so the robot's pixels of a render that draws it match the photo."""
    from mirage2matter.gaussians.robot import mesh_gaussians
    from mirage2matter.robots import get_robot
    from mirage2matter.robots.surface import robot_surface

    links = robot_surface(get_robot("panda"), q)
    out = {}
    for link, g in mesh_gaussians(links, spacing).items():
        T = next(s.T_base_link for s in links if s.link == link)
        uv, _ = cam.project(g.means.numpy() @ T[:3, :3].T + T[:3, 3])
        px = np.clip(np.floor(uv).astype(int), 0, [cam.width - 1, cam.height - 1])
        rgb = torch.as_tensor(photo[px[:, 1], px[:, 0]].astype(np.float32) / 255)
        out[link] = Gaussians(g.means, g.quats, g.log_scales, g.logit_opacities, rgb_to_sh_dc(rgb)[:, None, :])
    return out, links


@pytest.mark.skipif(not (SAMPLE / "ground_truth.json").is_file(), reason="samples/tabletop not built")
def test_head_view_draws_the_robot_at_the_photo_joints_in_the_scene_pass():
    """The photo shows the robot at its capture joints: drawn there from its Gaussians, the robot's pixels of the
    render match the photo's; the scene alone leaves the room behind it (here: nothing) in their place."""
    from mirage2matter.robots.kinematics import RobotKinematics

    gt, board, T_base_board, cam, photo = head_sample()
    q = gt["robot"]["capture_joints"]
    robot, links = photo_coloured_robot(cam, photo, q)
    scene = board_gaussians(board, T_base_board, pps=20)

    alone = check_head_view(scene, cam, photo, backend="cpu")
    drawn = check_head_view(scene, cam, photo, backend="cpu", robot=robot,
                            T_base_link=RobotKinematics("panda").link_poses(np.asarray(q)))  # fmt: skip
    mask = drawn.robot_mask
    # the robot's pixels are where its meshes project (the forearm across the board, the hand and upper arm)
    sil = robot_silhouette(cam, links)
    iou = (mask & sil).sum() / (mask | sil).sum()
    assert mask.mean() > 0.05 and iou > 0.85, (mask.mean(), iou)
    seen = photo.astype(np.float32) / 255
    robot_px = lambda img: 10 * np.log10(1 / np.mean((img[mask].astype(np.float32) / 255 - seen[mask]) ** 2))
    assert drawn.psnr_robot > robot_px(alone.render) + 8.0, (drawn.psnr_robot, robot_px(alone.render))
    assert abs(drawn.psnr_robot - robot_px(drawn.render)) < 0.1
    assert drawn.psnr > alone.psnr + 0.5  # the scene is the board alone: the rest is black, far from the photo
    # the rest is the scene's, as without the robot (but for the robot's soft edge: 8 mm Gaussians, ~1 m away)
    rest = ~grow_mask(mask, 10)
    assert np.abs(drawn.render[rest].astype(int) - alone.render[rest]).max() <= 2
    assert drawn.to_json()["robot_drawn"] and alone.robot_mask is None and "robot_drawn" not in alone.to_json()

    # at another joint state the robot is drawn elsewhere, and its pixels stop matching the photo
    moved = np.asarray(q, np.float64)
    moved[0] += 0.4
    off = check_head_view(scene, cam, photo, backend="cpu", robot=robot,
                          T_base_link=RobotKinematics("panda").link_poses(moved))  # fmt: skip
    assert (off.robot_mask & mask).sum() / (off.robot_mask | mask).sum() < 0.8
    assert robot_px(off.render) < drawn.psnr_robot - 4.0, (robot_px(off.render), drawn.psnr_robot)

"""A hybrid frame against a ground-truth render of the same state (the sample world in the Genesis twin).

Ground truth: Genesis renders the whole state (robot + the objects' textured meshes) from the head
camera; its segmentation gives the robot's true visible silhouette. Hybrid: the objects' Gaussians at
their physics poses rendered by the splat renderer, and a robot-only Genesis layer (objects moved out
of view for that render), composited depth-aware. The banana is put between the head camera and the
gripper, so the robot is only right if the compositing lets the banana hide it.
"""

from __future__ import annotations

import numpy as np
import pytest

pytestmark = pytest.mark.slow

SIZE = 224


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max(1, (a | b).sum()))


def _psnr(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None) -> float:
    d = (a.astype(np.float64) - b.astype(np.float64)) ** 2
    mse = d[mask].mean() if mask is not None else d.mean()
    return float(10 * np.log10(255.0**2 / max(mse, 1e-12)))


@pytest.fixture(scope="module")
def twin_world(sample_world_ws):
    from mirage2matter.gaussians.ply import read_ply
    from mirage2matter.render import MovablePart, SplatRenderOptions, SplatWorld
    from mirage2matter.sim.twin import Twin, TwinOptions
    from mirage2matter.world import load_world

    world = load_world(sample_world_ws() / "world")
    twin = Twin.build(world, TwinOptions(render=True, camera_sizes={"head": (SIZE, SIZE)}))
    parts = [MovablePart(o.name, read_ply(o.part.gaussians), o.placement.scale) for o in world.objects]
    # Objects only: the ground truth has no splat scene either (its table is Genesis' plane).
    splat = SplatWorld(None, parts, SplatRenderOptions(backend="cpu"))
    yield twin, splat
    twin.close()


def test_hybrid_frame_matches_ground_truth_and_objects_hide_the_gripper(twin_world) -> None:
    from mirage2matter.env.hybrid import render_K
    from mirage2matter.geometry.rotation import matrix_to_quat
    from mirage2matter.geometry.sim3 import invert_rigid
    from mirage2matter.render.composite import composite

    twin, splat = twin_world
    twin.reset(seed=0, randomize=False)
    T_base_cam, K, cw, ch = twin.camera("head")
    # Put the banana on the line from the head camera to the fingers, 35 % of the way from the fingers.
    tcp = (twin.T_base_link() @ twin.spec.T_ee_tcp)[:3, 3]
    eye = T_base_cam[:3, 3]
    banana = twin.bodies["banana"].entity
    T_b = twin.object_poses()["banana"]
    banana.set_pos(tcp + 0.35 * (eye - tcp) - T_b[:3, :3] @ np.zeros(3), zero_velocity=True)
    banana.set_quat(matrix_to_quat(T_b[:3, :3]), zero_velocity=True)
    poses = twin.object_poses()

    gt = twin.render_robot("head", SIZE, SIZE)  # the whole state: robot + object meshes
    # The robot-only layer: every object out of view for this one render.
    for name, b in twin.bodies.items():
        if b.kind == "object":
            b.entity.set_pos(np.array([0.0, 5.0 + len(name), -5.0]), zero_velocity=True)
    robot = twin.render_robot("head", SIZE, SIZE)

    splat.set_poses(poses)
    rgb, alpha, depth = splat.render(invert_rigid(T_base_cam), render_K(K, cw, ch, SIZE, SIZE), SIZE, SIZE)
    splat8 = np.clip(np.rint(rgb * 255), 0, 255).astype(np.uint8)
    hybrid, shown = composite(splat8, robot["rgb"], robot["robot_mask"], robot["depth"], depth, alpha)
    _, pasted = composite(splat8, robot["rgb"], robot["robot_mask"])  # the paper's baseline

    occluded = robot["robot_mask"] & ~gt["robot_mask"]  # robot pixels the banana hides in the ground truth
    assert occluded.sum() > 30, "the banana should hide part of the gripper from the head camera"
    iou = _iou(shown, gt["robot_mask"])
    iou_baseline = _iou(pasted, gt["robot_mask"])
    hidden = 1.0 - shown[occluded].mean()
    obj = alpha > 0.5
    psnr_robot = _psnr(hybrid, gt["rgb"], gt["robot_mask"])
    psnr_obj, psnr_all = _psnr(hybrid, gt["rgb"], obj & ~shown), _psnr(hybrid, gt["rgb"])
    print(
        f"\nrobot silhouette IoU: depth-aware {iou:.4f}, baseline {iou_baseline:.4f}; occluded robot pixels hidden: "
        f"{hidden:.3f} of {int(occluded.sum())}; PSNR robot pixels {psnr_robot:.1f} dB, object pixels {psnr_obj:.1f} "
        f"dB, full frame {psnr_all:.1f} dB"
    )
    assert iou >= 0.98
    assert hidden >= 0.9  # the banana in front of the gripper hides it
    assert iou_baseline < iou  # pasting the mask would draw the gripper over the banana
    np.testing.assert_array_equal(hybrid[shown], robot["rgb"][shown])


def test_robot_only_cameras_draw_the_same_robot_layer(twin_world) -> None:
    """datagen's twin draws only the robot (draw_scene=False: no plane/objects, mask from depth, no
    segmentation pass); its layer must equal the full scene's robot pixels."""
    from mirage2matter.sim.twin import Twin, TwinOptions

    twin, _ = twin_world
    lean = Twin.build(twin.cfg, TwinOptions(render=True, camera_sizes={"head": (SIZE, SIZE)}, draw_scene=False))
    try:
        for t in (twin, lean):
            t.reset(seed=3, randomize=True)
        full, robot = twin.render_robot("head"), lean.render_robot("head")
        from scipy.ndimage import binary_dilation, binary_erosion

        m_full, m_lean = full["robot_mask"], robot["robot_mask"]
        print(f"\nrobot pixels: full {int(m_full.sum())}, robot-only {int(m_lean.sum())}, "
              f"IoU {_iou(m_full, m_lean):.4f}")  # fmt: skip
        assert m_full.sum() > 500
        # Objects may hide robot pixels in the full render; otherwise the masks differ only at the outline
        # (Genesis' segmentation pass and its depth / colour pass disagree by a pixel at some edges).
        assert not (m_full & ~binary_dilation(m_lean, iterations=1)).any()
        assert _iou(m_full, m_lean) >= 0.97
        both = m_full & m_lean
        inner = binary_erosion(both, iterations=1)  # outline pixels blend with what is behind (plane / black)
        assert np.abs(full["rgb"][inner].astype(int) - robot["rgb"][inner]).max() <= 2
        np.testing.assert_allclose(full["depth"][both], robot["depth"][both], atol=1e-4)
        assert np.isinf(robot["depth"][~m_lean]).all()
    finally:
        lean.close()

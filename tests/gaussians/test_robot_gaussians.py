"""The robot's own Gaussians: on its meshes, posed by forward kinematics, coloured as the capture saw it."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from mirage2matter.calib.robot_view import robot_silhouette
from mirage2matter.gaussians.dataset import make_view
from mirage2matter.gaussians.model import Gaussians
from mirage2matter.gaussians.render import render
from mirage2matter.gaussians.robot import fit_robot_colours, mesh_gaussians, posed_robot
from mirage2matter.gaussians.sh import rgb_to_sh_dc
from mirage2matter.geometry.camera import Camera, look_at_pose
from mirage2matter.geometry.rotation import quat_to_matrix
from mirage2matter.robots import get_robot
from mirage2matter.robots.surface import robot_surface


@pytest.fixture(scope="module")
def robot(turned_panda):
    _, links = turned_panda
    return links, {link.link: link.T_base_link for link in links}


def test_mesh_gaussians_lie_on_the_links_in_the_models_colours(robot):
    links, T = robot
    lg = mesh_gaussians(links, spacing=0.008)
    assert set(lg) == {link.link for link in links}
    g = posed_robot(lg, T)
    from scipy.spatial import cKDTree

    from mirage2matter.robots.surface import sample_surface

    surface, _ = sample_surface(links, 0.002)
    assert np.percentile(cKDTree(surface).query(g.means.numpy())[0], 99) < 0.003
    # flat: the thinnest axis is a tenth of the others; the Panda's model is white and black
    s = np.sort(g.scales.numpy(), axis=1)
    assert np.all(s[:, 0] < 0.2 * s[:, 1])
    rgb = (g.sh[:, 0] * 0.28209479177387814 + 0.5).numpy()
    assert np.all((rgb.min(1) > 0.85) | (rgb.max(1) < 0.35))


def test_the_links_a_robot_camera_sees_close_up_get_finer_gaussians(robot):
    """The wrist camera's hand (and what is welded to it) and the fingers: Gaussians at half the spacing, smaller."""
    links, _ = robot
    assert {link.link for link in links if link.close_up} == {"link7", "hand", "left_finger", "right_finger"}
    lg = mesh_gaussians(links, spacing=0.008)
    for link in links:
        g = lg[link.link]
        density = len(g) / link.area  # Gaussians per m2 of surface
        expected = (1 / 0.004**2) if link.close_up else (1 / 0.008**2)
        assert 0.95 * expected < density < 1.05 * expected + 1 / link.area, (link.link, density, expected)
        assert torch.allclose(g.scales.max(dim=1).values, torch.tensor(0.6 * (0.004 if link.close_up else 0.008)))


def test_fitted_colours_are_the_captures_where_seen_and_the_parts_paint_behind(robot):
    """Keyframes of a robot painted orange (its own Gaussians re-coloured, rendered): the baked colours recover the
    paint on the held-out views' robot pixels, every Gaussian the keyframes saw is the paint (none drifts to another
    colour), and the back of a seen link, which no camera saw, takes its part's paint."""
    links, T = robot
    lg = mesh_gaussians(links, spacing=0.008)
    truth = {n: Gaussians(g.means, g.quats, g.log_scales, g.logit_opacities, g.sh.clone()) for n, g in lg.items()}
    for g in truth.values():
        g.sh[:, 0] = rgb_to_sh_dc(torch.tensor([0.87, 0.47, 0.16]))
    K = np.array([[150.0, 0, 80.0], [0, 150.0, 60.0], [0, 0, 1]])
    # cameras on the robot's +x side only: its back is never seen
    cams = [Camera(K, look_at_pose((0.2 + 1.4 * np.cos(a), 1.4 * np.sin(a), 0.7), (0.1, 0.0, 0.35)), 160, 120, f"c{i}")
            for i, a in enumerate(np.linspace(-0.9, 0.9, 7))]  # fmt: skip
    posed_truth = posed_robot(truth, T)
    views, sils = [], []
    for cam in cams:
        with torch.no_grad():
            img = render(posed_truth, torch.tensor(cam.viewmat, dtype=torch.float32),
                         torch.tensor(cam.K, dtype=torch.float32), 160, 120, torch.zeros(3), "cpu").rgb  # fmt: skip
        views.append(make_view(cam, img.numpy()))
        sils.append(robot_silhouette(cam, links))
    train, held = [0, 1, 2, 4, 6], [3, 5]
    fit = fit_robot_colours(lg, T, None, [views[i] for i in train], [sils[i] for i in train],
                            [views[i] for i in held], [sils[i] for i in held])  # fmt: skip
    assert fit.iterations == 0  # the bake alone by default
    assert fit.psnr_captured > fit.psnr_mesh + 10.0, (fit.psnr_mesh, fit.psnr_captured)
    assert fit.psnr_captured > 25.0
    paint = torch.tensor([0.87, 0.47, 0.16])
    for name, g in fit.link_gaussians.items():
        rgb = g.sh[:, 0] * 0.28209479177387814 + 0.5
        changed = (g.sh[:, 0] != lg[name].sh[:, 0]).any(dim=1)
        assert 0.0 < fit.seen_fraction[name] <= 1.0 or name in ("left_finger", "right_finger")
        assert float(changed.float().mean()) >= fit.seen_fraction[name] - 1e-6  # seen ones took the capture's
        # the seen part: the paint (a few edge Gaussians mix the silhouette's border)
        seen = np.sort((rgb[changed] - paint).abs().max(dim=1).values.numpy())[: int(fit.seen_fraction[name] * len(g))]
        assert len(seen) == 0 or np.percentile(seen, 95) < 0.1, (name, np.percentile(seen, 95))
        assert torch.equal(g.sh[~changed, 0], lg[name].sh[~changed, 0])
        if fit.seen_fraction[name] > 0.2:  # the unseen back too: the part's paint, not the model's white or black
            everywhere = (rgb - paint).abs().max(dim=1).values.numpy()
            assert np.percentile(everywhere, 95) < 0.1, (name, fit.seen_fraction[name], np.percentile(everywhere, 95))
    assert min(fit.seen_fraction.values()) < 0.9  # the back of the robot was not seen
    refined = fit_robot_colours(lg, T, None, [views[i] for i in train], [sils[i] for i in train],
                                [views[i] for i in held], [sils[i] for i in held], iterations=40)  # fmt: skip
    assert refined.iterations == 40 and refined.psnr_captured > 35.0  # the steps keep the paint


def test_a_keyframe_where_the_robot_stood_elsewhere_is_named(robot):
    """One keyframe filmed the robot at another joint state (it moved while filming): the fit names that view."""
    links, T = robot
    lg = mesh_gaussians(links, spacing=0.008)
    spec = get_robot("panda")
    q = np.asarray(spec.home, float)
    q[0] += 0.25
    q[3] += 0.4
    moved = {link.link: link.T_base_link for link in robot_surface(spec, q)}
    K = np.array([[150.0, 0, 80.0], [0, 150.0, 60.0], [0, 0, 1]])
    views, sils = [], []
    for i, a in enumerate(np.linspace(-0.9, 0.9, 6)):
        eye = (0.2 + 1.4 * np.cos(a), 1.4 * np.sin(a), 0.7)
        cam = Camera(K, look_at_pose(eye, (0.1, 0.0, 0.35)), 160, 120, f"k{i}")
        pose = moved if i == 4 else T
        with torch.no_grad():
            img = render(posed_robot(lg, pose), torch.tensor(cam.viewmat, dtype=torch.float32),
                         torch.tensor(cam.K, dtype=torch.float32), 160, 120, torch.zeros(3), "cpu").rgb  # fmt: skip
        views.append(make_view(cam, img.numpy()))
        sils.append(robot_silhouette(cam, links))  # where the capture joints put the robot
    fit = fit_robot_colours(lg, T, None, views, sils)
    assert fit.disagreeing == ["k4"], fit.view_error


def test_a_second_pose_shows_the_links_from_another_side(robot):
    """The robot painted orange on its +x side and blue behind, filmed from its +x side only, then turned by 2.8 rad
    about its base (a logged move): fitting both poses' keyframes, each at its own joint state, colours the back the
    first pose hid (from the first pose alone it takes the front's orange), and the views of the second pose agree
    with the rest."""
    links, T = robot
    lg = mesh_gaussians(links, spacing=0.012)
    truth = {n: Gaussians(g.means, g.quats, g.log_scales, g.logit_opacities, g.sh.clone()) for n, g in lg.items()}
    for name, g in truth.items():
        normal = np.asarray(quat_to_matrix(g.quats.numpy()))[:, :, 2] @ T[name][:3, :3].T  # base frame, first pose
        front = torch.from_numpy(normal[:, 0] > 0)[:, None]
        g.sh[:, 0] = rgb_to_sh_dc(torch.where(front, torch.tensor([0.87, 0.47, 0.16]), torch.tensor([0.2, 0.35, 0.8])))
    spec = get_robot("panda")
    q = np.asarray(spec.home_q(spec.gripper_open), float)
    q[0] = 2.8  # near the limit (2.897): the other side towards the cameras
    turned = {link.link: link.T_base_link for link in robot_surface(spec, q)}
    K = np.array([[150.0, 0, 80.0], [0, 150.0, 60.0], [0, 0, 1]])
    cams = [Camera(K, look_at_pose((0.2 + 1.4 * np.cos(a), 1.4 * np.sin(a), 0.7), (0.1, 0.0, 0.35)), 160, 120, f"c{i}")
            for i, a in enumerate(np.linspace(-0.9, 0.9, 7))]  # fmt: skip
    cams += [Camera(c.K, c.T_world_cam, 160, 120, f"d{i}") for i, c in enumerate(cams)]  # the same, after the move
    views, sils, pose_of = [], [], []
    for i, cam in enumerate(cams):
        p = int(i >= 7)
        pose = (T, turned)[p]
        with torch.no_grad():
            img = render(posed_robot(truth, pose), torch.tensor(cam.viewmat, dtype=torch.float32),
                         torch.tensor(cam.K, dtype=torch.float32), 160, 120, torch.zeros(3), "cpu").rgb  # fmt: skip
        views.append(make_view(cam, img.numpy()))
        sils.append(robot_silhouette(cam, robot_surface(spec, q) if p else links))
        pose_of.append(p)
    # held out: a view of the second pose, showing the side the first pose turned away from every camera
    train = [i for i in range(14) if i != 10]
    one = fit_robot_colours(lg, [T, turned], None, views[:7], sils[:7], [views[10]], [sils[10]],
                            view_pose_train=pose_of[:7], view_pose_eval=[1])  # fmt: skip
    both = fit_robot_colours(lg, [T, turned], None, [views[i] for i in train], [sils[i] for i in train],
                             [views[10]], [sils[10]], view_pose_train=[pose_of[i] for i in train],
                             view_pose_eval=[1])  # fmt: skip
    assert both.psnr_captured > one.psnr_captured + 5.0, (one.psnr_captured, both.psnr_captured)
    assert both.psnr_captured > both.psnr_mesh + 10.0 and both.disagreeing == [], both.view_error

"""The robot as Gaussians: per link, anchored to the link's mesh, coloured as the capture saw it.

Each link's surface is covered with flat Gaussians (discs in the surface's tangent plane, in the link's own frame, so
forward kinematics poses them like any movable part). They start in the mesh look, the model's material colours
(:func:`mesh_gaussians`: what a robot with no capture gets), and :func:`fit_robot_colours` takes their colours from the
keyframe pixels where the robot was seen: the frozen scene and the posed robot are rendered together, so what stands
in front of a link hides it, and only the robot's silhouette is read. Each Gaussian's colour is the average of the
pixels it was drawn into, weighted by its share of each (baked, like a texture), with its part's paint (the median of
the part's seen Gaussians; a part: one material of one link) as a prior of a few pixels; optional gradient steps
refine it. Positions, shapes and opacities stay the mesh's: only the colours are the capture's. A Gaussian that no
keyframe pixel fell on takes its part's paint; a part that no keyframe saw keeps the mesh's colours. The links a
camera on the robot sees from centimetres (the hand, the fingers) get finer Gaussians.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import torch

from ..geometry.rotation import matrix_to_quat
from ..geometry.sim3 import Sim3
from ..robots.surface import LinkSurface, sample_surface
from .model import Gaussians
from .transform import apply_sim3

__all__ = ["RobotFitResult", "fit_robot_colours", "mesh_gaussians", "posed_robot"]

SPACING_M = 0.004  # one Gaussian per 4 x 4 mm of link surface: ~60k for the Panda, finer than a keyframe pixel at 1 m
# The links a camera on the robot sees from centimetres (LinkSurface.close_up: the wrist camera's hand, the fingers)
# get Gaussians at half the spacing (the Panda: 58k -> 80k): at 4 mm their discs (sigma 2.4 mm) drew the fingers in
# the wrist view as blurred blobs. On the bundled sample (3 scripted grasps at 128 px, against the ground truth) the
# wrist view's pixels off the robot came 22.6 -> 22.9 dB with it; alone it left specks on the hand (each Gaussian
# a few keyframe pixels: 24.9 -> 23.2 dB on the robot's), which the part prior below evens out. Its cost: a hybrid
# frame at 224 px 229 / 231 -> 264 / 280 ms on 2 cores (`m2m bench datagen`, grasp banana, two runs each).
CLOSE_UP_SPACING = 0.5
OPACITY = 0.97
# The mesh's colour in a Gaussian's baked average counts as this many pixels' worth of observation: it decides only
# where next to no keyframe pixel fell. On the bundled sample's robot (3 scripted grasps, the robot's pixels in the
# hybrid frames against the ground truth's, head / wrist): 0.5 px 16.5 / 16.5 dB, 0.02 px 21.0 / 24.4, 0.001 px
# 23.8 / 25.0, 1e-4 px 24.5 / 25.0 dB; the gradient fit it replaced 20.8 / 24.1 dB (links seen barely, behind the
# front surface, were kept by Adam at full steps in their gradients' sign: white and blue specks, glare on the
# yellow link). The back of a link takes its front's colour: paint is mostly one colour per part.
MESH_PRIOR_PX = 1e-4
# A part's paint (the weighted median of its seen Gaussians' baked colours; a part: the faces of one link that share
# one material in the model) counts as this many pixels in each of its Gaussians' averages: what the keyframes saw
# barely or not at all (the hand's top, the fingers' inner faces; a finger's few keyframe pixels mixed with the table
# behind it) takes the part's paint, and a Gaussian many pixels saw keeps its own colour (logos, scuffs). On the
# bundled sample, the robot's pixels at a task's poses, head / wrist: 24.5 / 24.9 dB without, 24.9 / 25.1 (0.5 px),
# 24.9 / 25.3 (2 px), 24.5 / 25.4 (8 px); with the close-up spacing 24.8 / 25.3 dB, the fingers dark as painted
# instead of brown and orange. The held-out keyframes' robot pixels: 30.1 -> 29.3 dB (texture evened out).
PART_PRIOR_PX = 2.0
PART_MIN_SEEN = 10  # a part with fewer Gaussians seen (SEEN_PX) keeps the model's colour as its paint
SEEN_PX = 0.01  # seen_fraction: Gaussians that keyframe pixels gave at least a hundredth of a pixel's weight


def _tangent_frames(normals: np.ndarray) -> np.ndarray:
    """wxyz quaternions [M,4] of rotations whose z axis is each unit normal [M,3]."""
    helper = np.where(np.abs(normals[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    x = np.cross(helper, normals)
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    y = np.cross(normals, x)
    return np.asarray(matrix_to_quat(np.stack([x, y, normals], axis=2)))  # batched: [M,3,3] columns x, y, n


def mesh_gaussians(links: Sequence[LinkSurface], spacing: float = SPACING_M, seed: int = 0) -> dict[str, Gaussians]:
    """{link: Gaussians in the link's own frame}: flat discs on the link's surface in the model's colours, one per
    ``spacing`` x ``spacing`` of surface (times :data:`CLOSE_UP_SPACING` on the links seen close up)."""
    spacings = [spacing * (CLOSE_UP_SPACING if link.close_up else 1.0) for link in links]
    pts, owner, face = sample_surface(links, spacings, seed, frame="link", with_faces=True)
    out = {}
    for i, link in enumerate(links):
        sel = owner == i
        if not sel.any():
            continue
        tri = link.vertices_link[link.faces[face[sel]]]
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
        rgb = link.face_rgb[face[sel]] if link.face_rgb is not None else np.full((int(sel.sum()), 3), 0.6)
        m = int(sel.sum())
        scales = np.tile([0.6, 0.6, 0.08], (m, 1)) * spacings[i]
        out[link.link] = Gaussians.from_activated(
            torch.tensor(pts[sel], dtype=torch.float32), torch.tensor(_tangent_frames(n), dtype=torch.float32),
            torch.tensor(scales, dtype=torch.float32), torch.full((m,), OPACITY),
            rgb=torch.tensor(np.clip(rgb, 0.0, 1.0), dtype=torch.float32),
        )  # fmt: skip
    return out


def posed_robot(link_gaussians: dict[str, Gaussians], T_base_link: dict[str, np.ndarray]) -> Gaussians:
    """Every link's Gaussians moved to its pose [4,4] in the base frame, concatenated in ``link_gaussians``' order."""
    parts = []
    for name, g in link_gaussians.items():
        T = np.asarray(T_base_link[name], np.float64)
        parts.append(apply_sim3(g, Sim3(1.0, T[:3, :3], T[:3, 3])))
    return Gaussians.concat(parts)


@dataclass
class RobotFitResult:
    """What fitting the robot's colours to the capture did.

    link_gaussians   {link: Gaussians, link frame}, colours fitted where seen
    seen_fraction    {link: fraction of its Gaussians that training pixels gave at least SEEN_PX of weight}
    psnr_mesh        PSNR (dB) on the robot's pixels of the held-out keyframes, the mesh look (the fallback)
    psnr_captured    the same with the fitted colours
    iterations       gradient steps taken after the bake
    view_error       {training view: mean |fitted - photo| on its robot pixels}
    disagreeing      training views whose error is past DISAGREE_FACTOR x the median (and DISAGREE_MIN): the robot
                     there is not where the capture joints put it (it moved while filming, or the view's pose is off)
    """

    link_gaussians: dict[str, Gaussians]
    seen_fraction: dict[str, float]
    psnr_mesh: float | None
    psnr_captured: float | None
    iterations: int
    view_error: dict[str, float] = field(default_factory=dict)
    disagreeing: list[str] = field(default_factory=list)


# A view whose robot pixels the fitted colours explain this much worse than the median view's, and by at least this
# mean absolute error (colour units 0..1), disagrees with the rest.
DISAGREE_FACTOR = 3.0
DISAGREE_MIN = 0.08


def _robot_pixels(silhouette: np.ndarray, valid: torch.Tensor | None) -> torch.Tensor:
    """The pixels the loss and the figures read: the robot's silhouette eroded by a pixel (its edge mixes the robot
    with what is behind it), and valid in the view."""
    import cv2

    core = cv2.erode(silhouette.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    m = torch.from_numpy(core)
    return m if valid is None else m & valid


def _render(scene: Gaussians | None, robot: Gaussians, view, backend: str, background: torch.Tensor) -> torch.Tensor:
    from .render import render

    g = robot if scene is None else Gaussians.concat([scene, robot])
    return render(g, view.viewmat, view.K, view.width, view.height, background, backend).rgb


def _with_dc(robot: Gaussians, dc: torch.Tensor) -> Gaussians:
    """``robot`` with its colours' DC term ``dc`` [N,3] (the rest of its SH kept)."""
    sh = torch.cat([dc[:, None], robot.sh[:, 1:]], dim=1)
    return Gaussians(robot.means, robot.quats, robot.log_scales, robot.logit_opacities, sh)


def _psnr(views, silhouettes, scene, robots, view_pose, dc, backend, background) -> float | None:
    se, n = 0.0, 0
    with torch.no_grad():
        for v, sil, p in zip(views, silhouettes, view_pose, strict=True):
            m = _robot_pixels(sil, v.mask)
            if int(m.sum()) < 50:
                continue
            rgb = _render(scene, _with_dc(robots[p], dc), v, backend, background).clamp(0, 1)
            d = (rgb - v.image)[m]
            se += float((d**2).sum())
            n += int(d.numel())
    return None if n == 0 else float(10 * np.log10(1.0 / max(se / n, 1e-12)))


def _weighted_median(x: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """[C]: per column of ``x`` [M,C], the value where the weights ``w`` [M] (sorted by that column) reach half."""
    out = []
    for c in range(x.shape[1]):
        order = torch.argsort(x[:, c])
        cum = torch.cumsum(w[order], 0)
        out.append(x[order[int(torch.searchsorted(cum, cum[-1] / 2).clamp_max(len(cum) - 1))], c])
    return torch.stack(out)


def _parts(link_sizes: Sequence[int], dc: torch.Tensor) -> torch.Tensor:
    """[N] int: each Gaussian's part, its link (``link_sizes``: Gaussians per link, in order) and its model colour
    (``dc`` [N,3]: the mesh look, one per material)."""
    link = torch.repeat_interleave(torch.arange(len(link_sizes)), torch.as_tensor(list(link_sizes)))
    key = torch.cat([link[:, None].to(dc.dtype), dc.detach().cpu()], dim=1)
    return torch.unique(key, dim=0, return_inverse=True)[1]


def _bake(views, silhouettes, scene, robots, view_pose, dc, backend, background,
          parts: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:  # fmt: skip
    """Each Gaussian's colour as the average of the robot pixels it was drawn into, each pixel weighted by the
    Gaussian's share of it (its blend weight alpha * T: the render's derivative with respect to its colour, so the
    scene in front and the other links occlude as in the picture), the mesh's colour (``dc`` [N,3]) counted as
    :data:`MESH_PRIOR_PX` pixels and its part's paint (``parts`` [N], :func:`_parts`) as :data:`PART_PRIOR_PX`.
    -> (the baked DC [N,3], each Gaussian's summed weight [N] in pixels)."""
    from .sh import SH_C0, rgb_to_sh_dc

    num = torch.zeros_like(dc)
    den = torch.zeros_like(dc)
    for v, sil, p in zip(views, silhouettes, view_pose, strict=True):
        m = _robot_pixels(sil, v.mask)
        if int(m.sum()) < 50:
            continue
        x = dc.detach().clone().requires_grad_(True)
        rgb = _render(scene, _with_dc(robots[p], x), v, backend, background)
        mf = m[..., None].to(rgb.dtype).expand_as(rgb)
        num += torch.autograd.grad(rgb, x, grad_outputs=v.image * mf, retain_graph=True)[0]
        den += torch.autograd.grad(rgb, x, grad_outputs=mf)[0]
    weight = den / SH_C0  # d colour / d DC is the DC's basis constant times the blend weight
    mesh_rgb = dc.detach() * SH_C0 + 0.5
    w = weight.mean(dim=1)
    # each part's paint from the Gaussians' own averages (the mesh's colour where next to no pixel fell)
    own = (num / SH_C0 + MESH_PRIOR_PX * mesh_rgb) / (weight + MESH_PRIOR_PX)
    paint = mesh_rgb.clone()
    parts = parts.to(w.device)
    for k in torch.unique(parts):
        in_part = parts == k
        seen = in_part & (w >= SEEN_PX)
        if int(seen.sum()) >= PART_MIN_SEEN:
            paint[in_part] = _weighted_median(own[seen], w[seen])
    prior = MESH_PRIOR_PX * mesh_rgb + PART_PRIOR_PX * paint
    rgb = (num / SH_C0 + prior) / (weight + MESH_PRIOR_PX + PART_PRIOR_PX)
    return rgb_to_sh_dc(rgb.clamp(0.0, 1.0)), w


def fit_robot_colours(
    link_gaussians: dict[str, Gaussians],
    T_base_link: dict[str, np.ndarray] | Sequence[dict[str, np.ndarray]],
    scene: Gaussians | None,
    views_train: Sequence,
    silhouettes_train: Sequence[np.ndarray],
    views_eval: Sequence = (),
    silhouettes_eval: Sequence[np.ndarray] = (),
    iterations: int = 0,
    lr: float = 0.02,
    backend: str = "cpu",
    background: Sequence[float] = (0.0, 0.0, 0.0),
    seed: int = 0,
    view_pose_train: Sequence[int] | None = None,
    view_pose_eval: Sequence[int] | None = None,
) -> RobotFitResult:
    """Fit the colours (SH DC) of the robot's Gaussians to the keyframes (``views_*``: ``gaussians.train.View``,
    undistorted, at the scene's training size) on the robot's pixels (``silhouettes_*`` [H,W] bool per view: the
    robot at the joint state that view saw), the frozen ``scene`` rendered with it: the colours baked from those
    pixels (each Gaussian's blend-weighted average), then ``iterations`` Adam steps of the L1 fit on the Gaussians
    seen (0: the bake alone; on the bundled sample 300 steps raised the held-out keyframes' robot pixels 30.1 -> 31.3
    dB but lowered the robot's at the poses a task moves it to, 24.5 -> 23.8 dB head, 25.0 -> 24.7 wrist).

    ``T_base_link``: the links' poses at the capture joint state, or a list of them, one per pose the robot held
    while filmed, with ``view_pose_*`` the pose of each view (default: the first). The colours are one set: each link
    seen from another side at the second pose gets its colours there."""
    names = list(link_gaussians)
    poses = [T_base_link] if isinstance(T_base_link, dict) else list(T_base_link)
    robots = [posed_robot(link_gaussians, T).map(lambda t: t.detach()) for T in poses]
    pose_train = list(view_pose_train) if view_pose_train is not None else [0] * len(views_train)
    pose_eval = list(view_pose_eval) if view_pose_eval is not None else [0] * len(views_eval)
    sizes = [len(link_gaussians[n]) for n in names]
    bg = torch.as_tensor(background, dtype=torch.float32)
    scene = None if scene is None else scene.map(lambda t: t.detach())
    usable = [i for i, (v, s) in enumerate(zip(views_train, silhouettes_train, strict=True))
              if int(_robot_pixels(s, v.mask).sum()) >= 50]  # fmt: skip
    dc0 = robots[0].sh[:, 0].clone()
    psnr_mesh = _psnr(views_eval, silhouettes_eval, scene, robots, pose_eval, dc0, backend, bg)
    baked, weight = _bake(views_train, silhouettes_train, scene, robots, pose_train, dc0, backend, bg,
                          _parts(sizes, dc0))  # fmt: skip
    seen = weight >= SEEN_PX
    dc = baked.clone().requires_grad_(True)
    steps = 0
    if usable and iterations:
        # only the Gaussians the keyframes saw move: a barely touched one would take full Adam steps in its
        # gradient's sign
        movable = seen[:, None].to(dc.dtype)
        opt = torch.optim.Adam([dc], lr=lr)
        rng = np.random.default_rng(seed)
        for steps in range(1, iterations + 1):  # noqa: B007 (reported after the loop)
            i = usable[int(rng.integers(len(usable)))]
            v = views_train[i]
            m = _robot_pixels(silhouettes_train[i], v.mask)
            rgb = _render(scene, _with_dc(robots[pose_train[i]], dc), v, backend, bg)
            loss = (rgb - v.image).abs()[m].mean()
            opt.zero_grad()
            loss.backward()
            dc.grad *= movable
            opt.step()
    fitted = dc.detach()
    psnr_captured = _psnr(views_eval, silhouettes_eval, scene, robots, pose_eval, fitted, backend, bg)
    view_error = {}
    with torch.no_grad():
        for i in usable:
            v = views_train[i]
            m = _robot_pixels(silhouettes_train[i], v.mask)
            rgb = _render(scene, _with_dc(robots[pose_train[i]], fitted), v, backend, bg)
            view_error[v.name] = float((rgb - v.image).abs()[m].mean())
    median = float(np.median(list(view_error.values()))) if view_error else 0.0
    disagreeing = [n for n, e in view_error.items() if e > max(DISAGREE_FACTOR * median, DISAGREE_MIN)]
    out, frac, start = {}, {}, 0
    for name, size in zip(names, sizes, strict=True):
        g = link_gaussians[name]
        new_sh = g.sh.detach().clone()
        new_sh[:, 0] = fitted[start : start + size]
        out[name] = Gaussians(g.means.detach(), g.quats.detach(), g.log_scales.detach(), g.logit_opacities.detach(),
                              new_sh)  # fmt: skip
        frac[name] = float(seen[start : start + size].float().mean())
        start += size
    return RobotFitResult(out, frac, psnr_mesh, psnr_captured, steps, view_error, disagreeing)

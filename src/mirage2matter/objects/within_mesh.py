"""An object's Gaussians held inside its mesh: what the camera sees of an object is what physics holds.

Trained against masks over a black background, an object's 3DGS grows a shell of soft Gaussians a few mm outside its
surface (the masks' edges are a pixel or two wide; nothing outside them costs anything). On the bundled sample 58 % of
the banana's Gaussian centres lay outside its mesh and its Gaussians covered 1.30x the mesh's footprint seen from above
(the mesh itself 1.05x the truth): a policy trained on those pictures learns a fatter banana than the one its fingers
close on.

Held: each centre outside (or less than ``tol`` inside) moves along the nearest face's normal to ``tol`` inside;
each principal axis whose end at ``REACH`` standard deviations lies outside is shortened to where it leaves the mesh
(bisection). Gaussians well inside are untouched, bit for bit. Done once after training the shell's colours are lost
(the banana's held-out masked PSNR 33.99 -> 26.01 dB: what showed was the shell); done as the constraint of a short
retraining (:class:`HoldInside`, every few steps: the objects stage's last pruning round) the Gaussians inside take
the colours over. What the mesh gets wrong then shows in the pictures too.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .align import signed_distance_and_normal

__all__ = ["REACH", "HoldInside", "hold_inside", "keep_within_mesh"]

REACH = 2.0  # standard deviations of a Gaussian that must end inside (at 2 sigma its alpha is 14 % of its peak)
BISECTIONS = 8  # an axis is shortened to a multiple of 1/256 of its reach
MIN_SHRINK = 1.0 / 2**BISECTIONS


def hold_inside(mesh, means: np.ndarray, quats: np.ndarray, log_scales: np.ndarray,
                tol: float = 0.0005) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:  # fmt: skip
    """(means [N,3], log_scales [N,3]) of Gaussians (``means``, ``quats`` wxyz [N,4], ``log_scales``; ``mesh``'s frame)
    held inside the watertight ``mesh`` (trimesh), and figures: ``signed`` [N] each centre's signed distance before
    (> 0 inside), ``moved`` [N] and ``shrunk`` [N] bool."""
    from ..geometry.rotation import quat_to_matrix

    mu = np.asarray(means, np.float64)
    n = len(mu)
    signed, normal = signed_distance_and_normal(mesh, mu)
    moved = signed < tol
    mu_new = mu.copy()
    todo, now, n_face = moved.copy(), signed.copy(), normal.copy()
    for _ in range(3):  # onto the surface, tol inside, along the nearest face's normal (again past an edge or corner)
        mu_new[todo] -= n_face[todo] * (tol - now[todo])[:, None]
        now[moved], n_face[moved] = signed_distance_and_normal(mesh, mu_new[moved])
        todo = moved & (now < 0.5 * tol)
        if not todo.any():
            break
    inside = now > 0  # a centre still outside after three moves (a sliver of the mesh) keeps its axes: caller drops it

    # each principal axis's two ends at REACH sigma: an end outside shortens that axis to where its segment leaves
    R = np.asarray(quat_to_matrix(np.asarray(quats, np.float64)))  # [N,3,3], columns = axes
    scales = np.exp(np.asarray(log_scales, np.float64))  # [N,3]
    shrink = np.ones((n, 3))
    for axis in range(3):
        reach = R[:, :, axis] * (REACH * scales[:, axis])[:, None]  # [N,3]
        for sign in (1.0, -1.0):
            shrink[:, axis] = np.minimum(shrink[:, axis], _inside_fraction(mesh, mu_new, sign * reach, inside))
    shrink = np.maximum(shrink, MIN_SHRINK)
    shrunk = (shrink < 1.0).any(1)
    log_new = np.array(log_scales, np.float64, copy=True)
    log_new[shrunk] += np.log(shrink[shrunk])
    return mu_new, log_new, {"signed": signed, "moved": moved, "shrunk": shrunk, "outside_after": ~inside}


class HoldInside:
    """A training constraint (``gaussians.train.Constraint``): every ``every`` steps the Gaussians held inside
    ``mesh`` (the cameras' frame)."""

    def __init__(self, mesh, every: int = 25, tol: float = 0.0005) -> None:
        self.mesh, self.every, self.tol = mesh, every, tol

    def __call__(self, means, quats, log_scales):
        import torch

        mu, log_s, _ = hold_inside(self.mesh, means.detach().cpu().numpy(), quats.detach().cpu().numpy(),
                                   log_scales.detach().cpu().numpy(), self.tol)  # fmt: skip
        changed = lambda old, new: torch.as_tensor(new, dtype=old.dtype, device=old.device)  # noqa: E731
        return changed(means, mu), changed(log_scales, log_s)


def keep_within_mesh(g, mesh, tol: float = 0.0005, drop: float = 0.002) -> tuple[Any, dict[str, Any]]:
    """``g`` (Gaussians, in ``mesh``'s frame) held inside the watertight ``mesh`` (trimesh) to within ``tol`` m (see
    :func:`hold_inside`); centres more than ``drop`` m outside removed. Returns the new Gaussians and figures."""
    import torch

    from ..gaussians.model import Gaussians

    n_all = len(g)
    if n_all == 0:
        return g, {"gaussians": 0}
    means, log_scales, fig = hold_inside(mesh, g.means.detach().cpu().numpy(), g.quats.detach().cpu().numpy(),
                                         g.log_scales.detach().cpu().numpy(), tol)  # fmt: skip
    keep = (fig["signed"] > -drop) & ~fig["outside_after"]
    changed = fig["moved"] | fig["shrunk"]  # the others keep their very numbers
    rows = torch.from_numpy(np.flatnonzero(changed))
    new_means, new_log_scales = g.means.detach().clone(), g.log_scales.detach().clone()
    new_means[rows] = torch.as_tensor(means[changed], dtype=new_means.dtype, device=new_means.device)
    new_log_scales[rows] = torch.as_tensor(log_scales[changed], dtype=new_log_scales.dtype, device=new_means.device)
    out = Gaussians(new_means, g.quats.detach().clone(), new_log_scales, g.logit_opacities.detach().clone(),
                    g.sh.detach().clone())  # fmt: skip
    out = out.select(torch.from_numpy(keep).to(new_means.device))
    figures = {
        "gaussians": n_all,
        "centres_outside": float((fig["signed"] < 0).mean()),
        "moved_inside": int((fig["moved"] & keep).sum()),
        "squashed": int((fig["shrunk"] & keep).sum()),
        "dropped": int((~keep).sum()),
        "tolerance_m": tol,
    }
    return out, figures


def _inside_fraction(mesh, start: np.ndarray, step: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """[N] per row the fraction t of the segment start + t step (start inside the mesh) that stays inside: 1 where its
    end is inside (or the row is not in ``rows``), else bisected to 1/2**BISECTIONS (the segment may leave and come
    back; the end decides)."""
    from .inside import points_inside

    t = np.ones(len(start))
    out = np.zeros(len(start), bool)
    out[rows] = ~points_inside(mesh.vertices, mesh.faces, start[rows] + step[rows])
    idx = np.flatnonzero(out)
    if len(idx) == 0:
        return t
    lo, hi = np.zeros(len(idx)), np.ones(len(idx))
    for _ in range(BISECTIONS):
        mid = 0.5 * (lo + hi)
        ins = points_inside(mesh.vertices, mesh.faces, start[idx] + mid[:, None] * step[idx])
        lo, hi = np.where(ins, mid, lo), np.where(ins, hi, mid)
    t[idx] = lo
    return t

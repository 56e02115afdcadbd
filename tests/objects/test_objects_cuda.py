"""Object training on the GPU: test_objects_sample.py's small banana run (matting, object 3DGS, mesh,
alignment) with every render and training step on gsplat, held to the same bounds. Skipped without a CUDA
GPU and gsplat."""

from __future__ import annotations

import numpy as np
import trimesh
from test_objects_sample import SMALL, _gt_workspace, chamfer, gt_mesh_base, mask_ious, placed_mesh, run_objects

from fixtures.cuda import CUDA_MARKS
from mirage2matter.gaussians.ply import read_ply
from mirage2matter.geometry.sim3 import Sim3
from mirage2matter.objects.reconstruct import ObjectsConfig

pytestmark = CUDA_MARKS


def test_banana_small_run_on_the_gpu(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("M2M_RENDER_BACKEND", "cuda")  # "auto" everywhere in the objects stage -> gsplat
    ws = _gt_workspace(tmp_path_factory, "objects_cuda", 16)
    out = run_objects(ws, ObjectsConfig(names=["banana"], **SMALL))
    mesh, align = placed_mesh(ws, "banana")
    gt = gt_mesh_base("banana")
    assert mesh.is_watertight
    assert chamfer(mesh, gt) < 0.006
    assert 0.2 < mesh.volume / gt.volume < 1.5
    assert np.median(mask_ious(ws, "banana")) > 0.5
    g = read_ply(ws / "objects" / "banana" / "gaussians.ply")
    opaque = g.means[g.opacities > 0.5].numpy().astype(np.float64)
    on_base = Sim3.from_json(align["sim3_obj_to_base"]).apply(opaque)
    assert np.median(np.abs(trimesh.proximity.signed_distance(gt, on_base[:2000]))) < 0.004
    assert out["banana"]["gaussians"]["heldout"]["psnr_masked"] > 20.0

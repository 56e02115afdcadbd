import numpy as np
import pytest
import torch

from fixtures.gaussians import random_gaussians
from mirage2matter.gaussians import Gaussians
from mirage2matter.gaussians.synthetic import (
    ROOM_MAX,
    ROOM_MIN,
    TABLE_MAX_XY,
    TABLE_MIN_XY,
    TABLE_ROI_MAX,
    TABLE_ROI_MIN,
    TABLE_TOP_Z,
    orbit_cameras,
    tabletop_scene,
)

N = 20_000


@pytest.fixture(scope="module")
def scene() -> Gaussians:
    return tabletop_scene(N, sh_degree=3, seed=0)


def _quat_to_matrix(q: torch.Tensor) -> torch.Tensor:
    """Independent wxyz -> rotation matrix [N,3,3] for checking orientations."""
    q = q / q.norm(dim=1, keepdim=True)
    w, x, y, z = q.unbind(1)
    return torch.stack(
        [
            torch.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], 1),
            torch.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], 1),
            torch.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], 1),
        ],
        1,
    )


def _in_box(p: torch.Tensor, lo, hi) -> torch.Tensor:
    return ((p >= torch.tensor(lo)) & (p <= torch.tensor(hi))).all(dim=1)


def _project(means: np.ndarray, viewmat: np.ndarray, k: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    pc = means @ viewmat[:3, :3].T + viewmat[:3, 3]
    uv = pc @ k.T
    return uv[:, :2] / uv[:, 2:3], pc[:, 2]


@pytest.mark.parametrize("n", [100, 101, 4321])
def test_exact_count_and_dtypes(n):
    g = tabletop_scene(n, sh_degree=1)
    assert len(g) == n
    assert g.sh.shape == (n, 4, 3)
    for t in g.tensors().values():
        assert t.dtype == torch.float32 and t.device.type == "cpu"
    g.check_finite()


def test_deterministic_for_seed_and_varies_across_seeds():
    a, b, c = tabletop_scene(2000, seed=3), tabletop_scene(2000, seed=3), tabletop_scene(2000, seed=4)
    for name, t in a.tensors().items():
        assert torch.equal(t, b.tensors()[name]), name
    assert not torch.equal(a.means, c.means)


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_sh_degree_respected(degree):
    g = tabletop_scene(500, sh_degree=degree)
    assert g.sh_degree == degree
    if degree > 0:
        rest = g.sh[:, 1:]
        assert 0.01 < rest.abs().mean() < 0.1  # small view-dependence, not zero


def test_rejects_bad_arguments():
    with pytest.raises(ValueError, match="100"):
        tabletop_scene(99)
    with pytest.raises(ValueError, match="sh_degree"):
        tabletop_scene(1000, sh_degree=4)
    with pytest.raises(ValueError, match="sh_degree"):
        random_gaussians(10, sh_degree=-1)


def test_means_inside_room(scene):
    assert bool(_in_box(scene.means, ROOM_MIN, ROOM_MAX).all())


def test_table_region_holds_a_large_share(scene):
    frac = _in_box(scene.means, TABLE_ROI_MIN, TABLE_ROI_MAX).float().mean().item()
    assert frac > 0.45
    # and the room is not empty either
    floor = (scene.means[:, 2] < 0.01).float().mean().item()
    assert 0.05 < floor < 0.4


def test_trained_scene_statistics(scene):
    op = scene.opacities
    assert (op > 0.6).float().mean() > 0.7
    assert (op < 0.5).float().mean() > 0.03
    s = scene.scales.sort(dim=1).values
    # flat discs: the thin axis is much smaller than the in-plane ones for most Gaussians
    assert (s[:, 0] < 0.3 * s[:, 1]).float().mean() > 0.9
    # colours vary (textures), not a single flat colour
    assert scene.sh[:, 0].std(dim=0).min() > 0.2


def test_floor_gaussians_thin_along_z(scene):
    floor = (scene.means[:, 2] < 0.005) & (scene.means[:, 0].abs() > 0.3)  # not the pedestal
    assert floor.sum() > 500
    rot = _quat_to_matrix(scene.quats[floor])
    thin = scene.log_scales[floor].argmin(dim=1)
    axis = rot[torch.arange(len(thin)), :, thin]  # world direction of the smallest-scale axis
    assert (axis[:, 2].abs() > 0.99).float().mean() > 0.99


def test_table_top_gaussians_thin_along_z(scene):
    m = scene.means
    top = (m[:, 2] - TABLE_TOP_Z).abs() < 0.002
    top &= _in_box(m[:, :2], (TABLE_MIN_XY[0] + 0.02, TABLE_MIN_XY[1] + 0.02), (TABLE_MAX_XY[0] - 0.02, 0.1))
    rot = _quat_to_matrix(scene.quats[top])
    thin = scene.log_scales[top].argmin(dim=1)
    axis = rot[torch.arange(len(thin)), :, thin]
    assert (axis[:, 2].abs() > 0.99).float().mean() > 0.97


def test_sizes_adapt_to_budget():
    small, large = tabletop_scene(2_000), tabletop_scene(50_000)
    ratio = small.scales.max(dim=1).values.median() / large.scales.max(dim=1).values.median()
    assert 2.0 < ratio < 8.0  # ~ sqrt(25) = 5 when coverage is kept


def test_random_gaussians():
    g = random_gaussians(1000, sh_degree=2, seed=1, extent=2.0)
    assert len(g) == 1000 and g.sh_degree == 2
    assert bool((g.means.abs() <= 2.0).all())
    op = g.opacities
    assert op.min() > 0.04 and op.max() < 0.995
    s = g.scales
    assert (s.max(dim=1).values / s.min(dim=1).values > 1.5).float().mean() > 0.5  # anisotropic
    assert torch.allclose(g.quats.norm(dim=1), torch.ones(1000), atol=1e-5)
    assert not torch.equal(g.means, random_gaussians(1000, sh_degree=2, seed=2, extent=2.0).means)


@pytest.mark.parametrize("size", [(224, 224), (640, 480)])
def test_orbit_cameras_look_at_target(size, scene):
    w, h = size
    target = np.array([0.55, 0.0, 0.8])
    cams = orbit_cameras(5, w, h, target=tuple(target))
    assert len(cams) == 5
    centres = []
    for viewmat, k in cams:
        assert viewmat.shape == (4, 4) and k.shape == (3, 3)
        assert viewmat.dtype == np.float64 and k.dtype == np.float64
        r = viewmat[:3, :3]
        np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(r) == pytest.approx(1.0)
        assert k[0, 0] == pytest.approx(0.5 * w / np.tan(np.radians(30)))
        assert k[0, 0] == k[1, 1]
        uv, depth = _project(target[None], viewmat, k)
        np.testing.assert_allclose(uv[0], [w / 2, h / 2], atol=1e-9)
        assert depth[0] > 1.0
        # z up in the world is up in the image: image y (down) points against world z
        assert r[1, 2] < 0
        centre = -r.T @ viewmat[:3, 3]
        centres.append(centre)
        assert bool(_in_box(torch.tensor(centre[None]), ROOM_MIN, ROOM_MAX).all())

        # most of the table top and its objects are in view
        roi = scene.means[_in_box(scene.means, TABLE_ROI_MIN, TABLE_ROI_MAX)].double().numpy()
        uv, depth = _project(roi, viewmat, k)
        inside = (depth > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
        assert inside.mean() > 0.8
    # distinct viewpoints
    centres = np.array(centres)
    assert np.linalg.norm(centres[0] - centres[-1]) > 1.0


def test_orbit_cameras_deterministic():
    a, b = orbit_cameras(3, 64, 48, seed=5), orbit_cameras(3, 64, 48, seed=5)
    for (va, ka), (vb, kb) in zip(a, b, strict=True):
        np.testing.assert_array_equal(va, vb)
        np.testing.assert_array_equal(ka, kb)

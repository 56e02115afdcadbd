import json
import math

import numpy as np
import pytest
import torch

from mirage2matter.geometry.rotation import axis_angle_to_matrix, random_rotation
from mirage2matter.geometry.sim3 import Sim3


def _random_sim3(seed: int) -> Sim3:
    rng = np.random.default_rng(seed)
    return Sim3(float(rng.uniform(0.3, 3.0)), random_rotation(seed=rng), rng.normal(size=3))


def _h(x: np.ndarray) -> np.ndarray:
    return np.concatenate([x, np.ones((*x.shape[:-1], 1))], axis=-1)


def test_identity_and_matrix_layout():
    ident = Sim3.identity()
    np.testing.assert_array_equal(ident.matrix, np.eye(4))
    s = Sim3(2.0, axis_angle_to_matrix(np.array([0, 0, 1.0]), math.pi / 2), [1.0, 2.0, 3.0])
    # x = (1, 0, 0): rotate to (0, 1, 0), scale to (0, 2, 0), translate.
    np.testing.assert_allclose(s.apply(np.array([1.0, 0, 0])), [1.0, 4.0, 3.0], atol=1e-12)
    np.testing.assert_allclose(s.matrix[:3, :3], 2.0 * s.rotation)
    np.testing.assert_allclose(s.matrix[3], [0, 0, 0, 1])
    assert Sim3.from_matrix(s.matrix).allclose(s, atol=1e-12)


def test_apply_matches_homogeneous_matrix():
    s = _random_sim3(0)
    x = np.random.default_rng(1).normal(size=(5, 7, 3))
    np.testing.assert_allclose(s.apply(x), (_h(x) @ s.matrix.T)[..., :3], atol=1e-12)


def test_compose_and_inverse_match_matrix_products():
    a, b, c = _random_sim3(1), _random_sim3(2), _random_sim3(3)
    np.testing.assert_allclose((a @ b).matrix, a.matrix @ b.matrix, atol=1e-12)
    np.testing.assert_allclose((a @ b @ c).matrix, a.matrix @ b.matrix @ c.matrix, atol=1e-11)
    np.testing.assert_allclose(a.inverse().matrix, np.linalg.inv(a.matrix), atol=1e-12)
    assert (a @ a.inverse()).allclose(Sim3.identity(), atol=1e-12)
    assert (a.inverse() @ a).allclose(Sim3.identity(), atol=1e-12)
    x = np.random.default_rng(0).normal(size=(10, 3))
    np.testing.assert_allclose((a @ b).apply(x), a.apply(b.apply(x)), atol=1e-12)
    # Order matters (would pass for a commutative bug).
    assert not (a @ b).allclose(b @ a, atol=1e-6)


def test_apply_torch_keeps_type_dtype_and_grad():
    s = _random_sim3(4)
    x64 = np.random.default_rng(2).normal(size=(6, 3))
    for dtype in (torch.float32, torch.float64):
        xt = torch.tensor(x64, dtype=dtype, requires_grad=True)
        y = s.apply(xt)
        assert isinstance(y, torch.Tensor) and y.dtype == dtype and y.device == xt.device
        np.testing.assert_allclose(y.detach().numpy(), s.apply(x64), atol=1e-5 if dtype == torch.float32 else 1e-12)
        y.sum().backward()
        expected = np.broadcast_to((s.scale * s.rotation).sum(axis=0), (6, 3))
        np.testing.assert_allclose(xt.grad.numpy(), expected, atol=1e-5)
    y32 = s.apply(x64.astype(np.float32))
    assert isinstance(y32, np.ndarray) and y32.dtype == np.float32


def test_apply_rotation_and_pose():
    s = _random_sim3(5)
    R = random_rotation(4, seed=9)
    np.testing.assert_allclose(s.apply_rotation(R), s.rotation @ R, atol=1e-12)
    assert s.apply_rotation(torch.as_tensor(R, dtype=torch.float32)).dtype == torch.float32
    T = np.tile(np.eye(4), (4, 1, 1))
    T[:, :3, :3] = R
    T[:, :3, 3] = np.random.default_rng(3).normal(size=(4, 3))
    T2 = s.apply_pose(T)
    np.testing.assert_allclose(T2[:, :3, :3], s.rotation @ R, atol=1e-12)
    np.testing.assert_allclose(T2[:, :3, 3], s.apply(T[:, :3, 3]), atol=1e-12)
    # The pose stays rigid, so a camera-frame point at depth z reappears at depth s z: T2 (s x) = sim3(T x).
    x_cam = np.array([0.1, -0.2, 0.7])
    p = (T @ _h(x_cam))[..., :3]
    np.testing.assert_allclose((T2 @ _h(s.scale * x_cam))[..., :3], s.apply(p), atol=1e-12)
    np.testing.assert_array_equal(T2[:, 3], np.tile([0, 0, 0, 1.0], (4, 1)))


def test_json_round_trip_and_layout(tmp_path):
    s = _random_sim3(6)
    d = s.to_json()
    assert set(d) == {"scale", "rotation", "translation"}
    assert isinstance(d["scale"], float) and np.shape(d["rotation"]) == (3, 3) and len(d["translation"]) == 3
    assert Sim3.from_json(json.loads(json.dumps(d))).allclose(s, atol=0)
    path = tmp_path / "sub" / "sim3.json"
    s.save(path)
    assert Sim3.load(path).allclose(s, atol=0)
    assert json.loads(path.read_text()) == d
    assert [p.name for p in path.parent.iterdir()] == ["sim3.json"]  # no temp file left behind
    with pytest.raises(ValueError, match="lacks"):
        Sim3.from_json({"scale": 1.0, "rotation": np.eye(3).tolist()})


@pytest.mark.parametrize(
    ("scale", "rotation", "match"),
    [
        (0.0, np.eye(3), "scale"),
        (-1.0, np.eye(3), "scale"),
        (float("nan"), np.eye(3), "scale"),
        (1.0, 2.0 * np.eye(3), "orthonormal"),
        (1.0, np.diag([1.0, 1.0, -1.0]), "det"),
        (1.0, np.eye(3) + 1e-4, "orthonormal"),
        (1.0, np.eye(4), "shape"),
        (1.0, np.full((3, 3), np.nan), "NaN"),
    ],
)
def test_invalid_sim3_rejected(scale, rotation, match):
    with pytest.raises(ValueError, match=match):
        Sim3(scale, rotation, np.zeros(3))


def test_from_matrix_rejects_reflection_and_bad_last_row():
    M = np.eye(4)
    M[:3, :3] = np.diag([2.0, 2.0, -2.0])
    with pytest.raises(ValueError, match="det"):
        Sim3.from_matrix(M)
    M = np.eye(4)
    M[3, 0] = 1.0
    with pytest.raises(ValueError, match="last row"):
        Sim3.from_matrix(M)


def test_immutable_and_owns_its_arrays():
    R = random_rotation(seed=0)
    s = Sim3(1.0, R, np.zeros(3))
    R[0, 0] = 5.0  # caller's array changes; ours must not
    np.testing.assert_array_equal(s.rotation, random_rotation(seed=0))
    with pytest.raises(ValueError):
        s.rotation[0, 0] = 1.0
    with pytest.raises(AttributeError):
        s.scale = 2.0  # type: ignore[misc]
    assert s.is_rigid and not Sim3(1.5, np.eye(3), np.zeros(3)).is_rigid

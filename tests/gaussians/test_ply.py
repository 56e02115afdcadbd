"""3DGS PLY I/O against files built independently with plyfile, and every documented failure."""

from __future__ import annotations

from pathlib import Path
from typing import BinaryIO

import numpy as np
import plyfile
import pytest
import torch

from mirage2matter.gaussians.model import Gaussians
from mirage2matter.gaussians.ply import PlyFormatError, read_ply, write_ply

STANDARD_ORDER = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
TAIL = ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]


def random_gaussians(n: int, degree: int, seed: int = 0) -> Gaussians:
    gen = torch.Generator().manual_seed(seed)
    k = (degree + 1) ** 2
    return Gaussians(
        means=torch.randn(n, 3, generator=gen),
        quats=torch.randn(n, 4, generator=gen),
        log_scales=torch.randn(n, 3, generator=gen) - 3,
        logit_opacities=torch.randn(n, generator=gen),
        sh=torch.randn(n, k, 3, generator=gen),
    )


def reference_columns(g: Gaussians) -> dict[str, np.ndarray]:
    """Property name -> values, spelled out from the Inria layout definition (no reshapes)."""
    k = g.sh.shape[1]
    cols = {
        "x": g.means[:, 0],
        "y": g.means[:, 1],
        "z": g.means[:, 2],
        "opacity": g.logit_opacities,
    }
    for c in range(3):
        cols[f"f_dc_{c}"] = g.sh[:, 0, c]
        cols[f"scale_{c}"] = g.log_scales[:, c]
        for j in range(1, k):
            cols[f"f_rest_{c * (k - 1) + (j - 1)}"] = g.sh[:, j, c]
    for i in range(4):
        cols[f"rot_{i}"] = g.quats[:, i]
    return {name: v.numpy().astype(np.float32) for name, v in cols.items()}


def write_independent(path: Path, columns: dict[str, np.ndarray], order: list[str], text: bool = False) -> None:
    """Write a vertex element with plyfile directly, properties in ``order``."""
    n = len(next(iter(columns.values()))) if columns else 0
    arr = np.empty(n, dtype=[(name, columns[name].dtype.str) for name in order])
    for name in order:
        arr[name] = columns[name]
    plyfile.PlyData([plyfile.PlyElement.describe(arr, "vertex")], text=text, byte_order="<").write(str(path))


def assert_same(a: Gaussians, b: Gaussians) -> None:
    for name, t in a.tensors().items():
        u = getattr(b, name)
        assert u.dtype == torch.float32 and u.device.type == "cpu" and u.is_contiguous(), name
        assert u.shape == t.shape, name
        assert torch.equal(u, t.to(torch.float32)), name


# ---- happy paths --------------------------------------------------------------------------------
@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_round_trip_bit_exact(tmp_path: Path, degree: int) -> None:
    g = random_gaussians(257, degree, seed=degree)
    write_ply(tmp_path / "g.ply", g)
    back = read_ply(tmp_path / "g.ply")
    assert back.sh_degree == degree
    assert_same(g, back)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["g.ply"]  # no temporary left behind


@pytest.mark.parametrize("degree", [0, 3])
@pytest.mark.parametrize("extra", [False, True], ids=["all-float32", "extra-uint8"])
def test_independent_file_shuffled_order_loads(tmp_path: Path, degree: int, extra: bool) -> None:
    g = random_gaussians(50, degree, seed=7)
    cols = reference_columns(g)
    cols.update({n: np.zeros(50, np.float32) for n in ("nx", "ny", "nz")})
    if extra:  # an unknown property (ignored) that also takes read_ply off its all-float32 fast path
        cols["red"] = np.arange(50, dtype=np.uint8)
    order = list(cols)
    np.random.default_rng(1).shuffle(order)
    assert order[:3] != ["x", "y", "z"]
    write_independent(tmp_path / "other.ply", cols, order)
    assert_same(g, read_ply(tmp_path / "other.ply"))


def test_ascii_ply_without_normals_loads(tmp_path: Path) -> None:
    g = random_gaussians(5, 1, seed=3)
    cols = reference_columns(g)
    write_independent(tmp_path / "ascii.ply", cols, list(cols), text=True)
    back = read_ply(tmp_path / "ascii.ply")
    for name, t in g.tensors().items():
        # plain numpy: torch.testing's first call imports the distributed stack (~1 s)
        np.testing.assert_allclose(getattr(back, name).numpy(), t.numpy(), rtol=1e-6, atol=1e-6, err_msg=name)


@pytest.mark.parametrize("degree", [0, 2])
def test_written_file_is_standard_3dgs(tmp_path: Path, degree: int) -> None:
    g = random_gaussians(33, degree, seed=11)
    path = tmp_path / "g.ply"
    write_ply(path, g)
    assert path.read_bytes().startswith(b"ply\nformat binary_little_endian 1.0\n")
    ply = plyfile.PlyData.read(str(path))
    assert [e.name for e in ply.elements] == ["vertex"]
    v = ply["vertex"]
    n_rest = 3 * ((degree + 1) ** 2 - 1)
    assert [p.name for p in v.properties] == STANDARD_ORDER + [f"f_rest_{i}" for i in range(n_rest)] + TAIL
    assert all(v.data.dtype[name] == np.dtype("<f4") for name in v.data.dtype.names)
    for name, expect in reference_columns(g).items():
        np.testing.assert_array_equal(v[name], expect, err_msg=name)
    for name in ("nx", "ny", "nz"):
        assert not v[name].any()


def test_non_float32_input_is_written_as_float32(tmp_path: Path) -> None:
    g = random_gaussians(4, 1).map(lambda t: t.double())
    write_ply(tmp_path / "g.ply", g)
    assert_same(g.map(lambda t: t.float()), read_ply(tmp_path / "g.ply"))


@pytest.mark.parametrize("degree", [0, 3])
def test_zero_gaussians(tmp_path: Path, degree: int) -> None:
    write_ply(tmp_path / "empty.ply", random_gaussians(0, degree))
    back = read_ply(tmp_path / "empty.ply")
    assert len(back) == 0 and back.sh.shape == (0, (degree + 1) ** 2, 3) and back.quats.shape == (0, 4)


# ---- bad inputs ---------------------------------------------------------------------------------
def bad(path: Path, *fragments: str) -> None:
    with pytest.raises(PlyFormatError) as info:
        read_ply(path)
    msg = str(info.value)
    assert isinstance(info.value, ValueError)
    assert str(path) in msg, msg
    for frag in fragments:
        assert frag in msg, f"{frag!r} not in {msg!r}"


def test_missing_file(tmp_path: Path) -> None:
    bad(tmp_path / "absent.ply", "no such file")


def test_directory(tmp_path: Path) -> None:
    bad(tmp_path, "not a regular file")


def test_not_a_ply(tmp_path: Path) -> None:
    (tmp_path / "x.ply").write_text("solid cube\nendsolid\n")
    bad(tmp_path / "x.ply", "not a valid PLY")
    (tmp_path / "empty.ply").write_bytes(b"")
    bad(tmp_path / "empty.ply", "not a valid PLY")


def test_truncated_body(tmp_path: Path) -> None:
    write_ply(tmp_path / "t.ply", random_gaussians(10, 1))
    data = (tmp_path / "t.ply").read_bytes()
    (tmp_path / "t.ply").write_bytes(data[:-50])
    bad(tmp_path / "t.ply", "not a valid PLY")


def test_no_vertex_element(tmp_path: Path) -> None:
    face = np.zeros(2, dtype=[("a", "<i4")])
    plyfile.PlyData([plyfile.PlyElement.describe(face, "face")]).write(str(tmp_path / "f.ply"))
    bad(tmp_path / "f.ply", "no 'vertex' element", "face")


def test_plain_point_cloud(tmp_path: Path) -> None:
    cols = {n: np.ones(4, np.float32) for n in "xyz"} | {n: np.full(4, 200, np.uint8) for n in ("red", "green", "blue")}
    write_independent(tmp_path / "cloud.ply", cols, list(cols))
    bad(tmp_path / "cloud.ply", "does not look like a 3D Gaussian Splatting PLY", "f_dc_0", "opacity", "rot_3", "red")


def test_one_missing_property_is_named(tmp_path: Path) -> None:
    cols = reference_columns(random_gaussians(3, 0))
    order = [n for n in cols if n != "scale_2"]
    write_independent(tmp_path / "m.ply", cols, order)
    with pytest.raises(PlyFormatError, match=r"lacks scale_2 \(") as info:
        read_ply(tmp_path / "m.ply")
    assert "opacity" not in str(info.value).split("lacks")[1].split("(")[0]


def test_bad_f_rest_count(tmp_path: Path) -> None:
    cols = reference_columns(random_gaussians(3, 0))
    cols |= {f"f_rest_{i}": np.zeros(3, np.float32) for i in range(5)}
    write_independent(tmp_path / "r.ply", cols, list(cols))
    bad(tmp_path / "r.ply", "5 f_rest_* properties", "9 (degree 1)", "45 (degree 3)")


def test_f_rest_with_gap(tmp_path: Path) -> None:
    cols = reference_columns(random_gaussians(3, 1))
    cols["f_rest_9"] = cols.pop("f_rest_4")
    write_independent(tmp_path / "gap.ply", cols, list(cols))
    bad(tmp_path / "gap.ply", "missing f_rest_4")


def test_non_finite_values_named(tmp_path: Path) -> None:
    cols = reference_columns(random_gaussians(6, 1))
    cols["opacity"][[1, 4]] = np.nan
    cols["scale_1"][2] = np.inf
    cols["f_rest_7"][0] = -np.inf
    write_independent(tmp_path / "nan.ply", cols, list(cols))
    bad(tmp_path / "nan.ply", "NaN/Inf", "opacity: 2", "scale_1: 1", "f_rest_7: 1")


def test_double_overflow_is_reported_as_inf(tmp_path: Path) -> None:
    cols = reference_columns(random_gaussians(2, 0))
    cols["x"] = np.array([1e300, 0.0])  # finite in the file, not representable as float32
    write_independent(tmp_path / "big.ply", cols, list(cols))
    bad(tmp_path / "big.ply", "x: 1")


# ---- failing writes -----------------------------------------------------------------------------
def test_write_failure_leaves_nothing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def half_write(self: plyfile.PlyData, stream: BinaryIO) -> None:
        stream.write(b"ply\nformat binary_little_endian 1.0\n")
        raise OSError(28, "No space left on device (simulated)")

    monkeypatch.setattr(plyfile.PlyData, "write", half_write)
    with pytest.raises(OSError, match="simulated"):
        write_ply(tmp_path / "g.ply", random_gaussians(10, 2))
    assert list(tmp_path.iterdir()) == []


def test_write_failure_keeps_previous_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    old = random_gaussians(8, 1, seed=1)
    write_ply(tmp_path / "g.ply", old)

    def crash(self: plyfile.PlyData, stream: BinaryIO) -> None:
        stream.write(b"garbage")
        raise KeyboardInterrupt

    monkeypatch.setattr(plyfile.PlyData, "write", crash)
    with pytest.raises(KeyboardInterrupt):
        write_ply(tmp_path / "g.ply", random_gaussians(8, 1, seed=2))
    monkeypatch.undo()
    assert_same(old, read_ply(tmp_path / "g.ply"))
    assert [p.name for p in tmp_path.iterdir()] == ["g.ply"]


def test_write_refuses_non_finite(tmp_path: Path) -> None:
    g = random_gaussians(4, 0)
    g.log_scales[2, 1] = float("nan")
    with pytest.raises(ValueError, match="log_scales"):
        write_ply(tmp_path / "g.ply", g)
    assert list(tmp_path.iterdir()) == []


def test_write_into_missing_directory(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="does not exist"):
        write_ply(tmp_path / "nope" / "g.ply", random_gaussians(1, 0))

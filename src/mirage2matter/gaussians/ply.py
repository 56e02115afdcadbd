"""Gaussians <-> PLY in the Inria 3DGS layout, the format SuperSplat and every 3DGS viewer open.

One ``vertex`` element, binary little endian, float32 properties

    x y z  nx ny nz  f_dc_0 f_dc_1 f_dc_2  f_rest_0 .. f_rest_{3(K-1)-1}
    opacity  scale_0 scale_1 scale_2  rot_0 rot_1 rot_2 rot_3

with the *raw* parameters: ``opacity`` is the logit, ``scale_*`` are log scales, ``rot_*`` is the
wxyz quaternion, normals are unused (written as 0). ``f_rest`` is channel-major:
``f_rest[c*(K-1) + (k-1)] = sh[:, k, c]`` for k >= 1, so all red coefficients come first.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np
import plyfile
import torch

from ..atomic import atomic_write
from ..errors import M2MError
from ..inputs import MAX_LOG_SCALE
from .model import Gaussians
from .sh import MAX_SH_DEGREE, num_sh_bases

__all__ = ["PlyFormatError", "read_ply", "write_ply", "ply_property_names"]

_LAYOUT_HINT = "expected the Inria 3DGS layout: x y z [nx ny nz] f_dc_0..2 f_rest_* opacity scale_0..2 rot_0..3"
_REQUIRED = (
    ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity"]
    + [f"scale_{i}" for i in range(3)]
    + [f"rot_{i}" for i in range(4)]
)
_F_REST = re.compile(r"f_rest_(\d+)$")
# Valid f_rest counts: 3 channels x (K-1) higher-order coefficients per degree.
_REST_COUNTS = {3 * (num_sh_bases(d) - 1): d for d in range(MAX_SH_DEGREE + 1)}


class PlyFormatError(M2MError, ValueError):
    """A file that cannot be read as 3DGS Gaussians; the message names the file and the problem."""


def ply_property_names(sh_degree: int) -> list[str]:
    """The vertex properties ``write_ply`` emits for ``sh_degree``, in file order."""
    n_rest = 3 * (num_sh_bases(sh_degree) - 1)
    return (
        ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
        + [f"f_rest_{i}" for i in range(n_rest)]
        + ["opacity"]
        + [f"scale_{i}" for i in range(3)]
        + [f"rot_{i}" for i in range(4)]
    )


def _fail(path: Path, problem: str) -> PlyFormatError:
    return PlyFormatError(f"{path}: {problem}")


def read_ply(path: str | os.PathLike[str]) -> Gaussians:
    """Load Gaussians from a 3DGS PLY. Returns float32 CPU tensors; SH degree from the f_rest count.

    Property order in the file does not matter and unknown properties are ignored. Raises
    ``PlyFormatError`` (a ``ValueError``) naming the file for anything it cannot use.
    """
    path = Path(path)
    if not path.exists():
        raise _fail(path, "no such file")
    if not path.is_file():
        raise _fail(path, "not a regular file")
    try:
        ply = plyfile.PlyData.read(str(path))
    except plyfile.PlyParseError as e:
        raise _fail(path, f"not a valid PLY file ({e})") from e
    except OSError as e:
        raise _fail(path, f"cannot read file ({e.strerror or e})") from e
    except Exception as e:  # plyfile surfaces some malformed headers as ValueError/struct errors
        raise _fail(path, f"not a valid PLY file ({type(e).__name__}: {e})") from e

    elements = {el.name: el for el in ply.elements}
    if "vertex" not in elements:
        raise _fail(path, f"no 'vertex' element (elements: {sorted(elements) or 'none'}); {_LAYOUT_HINT}")
    vertex = elements["vertex"]
    scalar = {p.name for p in vertex.properties if not isinstance(p, plyfile.PlyListProperty)}
    present = [p.name for p in vertex.properties]

    missing = [name for name in _REQUIRED if name not in scalar]
    if missing:
        hint = ""
        if "packed_position" in scalar or "chunk" in elements:
            hint = " It looks like a compressed (SuperSplat) PLY; export an uncompressed PLY instead."
        raise _fail(
            path,
            f"does not look like a 3D Gaussian Splatting PLY: vertex element lacks {', '.join(missing)} "
            f"(has: {', '.join(present) or 'no properties'}); {_LAYOUT_HINT}. A plain point cloud "
            f"(e.g. x y z red green blue) cannot be loaded as Gaussians.{hint}",
        )

    rest_idx = sorted(int(m.group(1)) for name in scalar if (m := _F_REST.match(name)))
    n_rest = len(rest_idx)
    if n_rest not in _REST_COUNTS:
        valid = ", ".join(f"{c} (degree {d})" for c, d in _REST_COUNTS.items())
        raise _fail(path, f"{n_rest} f_rest_* properties; a 3DGS PLY has {valid}")
    if rest_idx != list(range(n_rest)):
        gaps = sorted(set(range(n_rest)) - set(rest_idx))
        raise _fail(path, f"f_rest_* properties are not numbered 0..{n_rest - 1} (missing f_rest_{gaps[0]})")
    degree = _REST_COUNTS[n_rest]
    k = num_sh_bases(degree)

    # Property names per output tensor, in the tensor's memory order. For sh that is [K, 3]:
    # (k, c) -> f_dc_c for k = 0, else f_rest_{c*(K-1) + k-1} (channel-major in the file).
    groups = {
        "means": ["x", "y", "z"],
        "quats": [f"rot_{i}" for i in range(4)],
        "log_scales": [f"scale_{i}" for i in range(3)],
        "logit_opacities": ["opacity"],
        "sh": [f"f_dc_{c}" if j == 0 else f"f_rest_{c * (k - 1) + j - 1}" for j in range(k) for c in range(3)],
    }
    try:
        arrays = _gather(vertex.data, groups)
    except (ValueError, TypeError) as e:  # e.g. a property declared with a non-numeric type
        raise _fail(path, f"cannot convert vertex properties to float32 ({e})") from e

    # Report per property, so the message points at the exact column a broken exporter wrote.
    bad: dict[str, int] = {}
    for key, names in groups.items():
        counts = (~np.isfinite(arrays[key])).sum(axis=0)
        bad |= {name: int(c) for name, c in zip(names, counts, strict=True) if c}
    if bad:
        ordered = sorted(bad.items(), key=lambda item: present.index(item[0]))
        shown = ", ".join(f"{name}: {c}" for name, c in ordered[:8])
        shown += f", ... ({len(ordered)} properties)" if len(ordered) > 8 else ""
        raise _fail(path, f"NaN/Inf values (property: rows affected, of {len(vertex.data)}): {shown}")

    # finite already; rotations that cannot be normalised and km-wide Gaussians are broken files too
    q = np.linalg.norm(arrays["quats"].astype(np.float64), axis=1)
    if len(q) and q.min() < 1e-8:
        raise _fail(path, f"Gaussian {int(np.argmin(q))} has a zero rotation quaternion (rot_0..rot_3)")
    top = arrays["log_scales"].max(axis=1) if len(q) else np.zeros(0)
    if len(top) and top.max() > MAX_LOG_SCALE:
        i = int(np.argmax(top))
        wide = np.exp(min(float(top[i]), 700.0))
        raise _fail(path, f"Gaussian {i} has log-scale {top[i]:.1f} (> {MAX_LOG_SCALE}: {wide:.3g} m wide); "
                    "not a splat of a real scene")  # fmt: skip
    n = len(vertex.data)
    return Gaussians(
        means=torch.from_numpy(arrays["means"]),
        quats=torch.from_numpy(arrays["quats"]),
        log_scales=torch.from_numpy(arrays["log_scales"]),
        logit_opacities=torch.from_numpy(arrays["logit_opacities"].reshape(n)),
        sh=torch.from_numpy(arrays["sh"].reshape(n, k, 3)),
    )


def _gather(data: np.ndarray, groups: dict[str, list[str]]) -> dict[str, np.ndarray]:
    """Copy named properties of a record array into contiguous float32 arrays [N, len(names)]."""
    n, fields = len(data), data.dtype.fields or {}
    f4 = np.dtype("<f4")
    if all(dt == f4 for dt, *_ in fields.values()) and data.dtype.itemsize == 4 * len(fields):
        # Common case (every 3DGS exporter): all properties float32 LE, packed. View the records as
        # a float matrix and gather each group's columns in one pass.
        matrix = data.view(f4).reshape(n, len(fields))
        col = {name: off // 4 for name, (_, off, *_) in fields.items()}
        # np.take, not matrix[:, idx]: fancy indexing returns a column-major (non-contiguous) result.
        return {key: np.take(matrix, [col[name] for name in names], axis=1) for key, names in groups.items()}
    out = {}
    with np.errstate(over="ignore", invalid="ignore"):  # float64 overflow -> Inf, reported by the caller
        for key, names in groups.items():
            arr = np.empty((n, len(names)), dtype=np.float32)
            for j, name in enumerate(names):
                arr[:, j] = data[name]
            out[key] = arr
    return out


def write_ply(path: str | os.PathLike[str], g: Gaussians) -> None:
    """Write ``g`` as a binary little-endian 3DGS PLY, atomically (temporary file, then rename).

    Values are stored as float32 (tensors on any device / dtype are converted). Refuses
    Gaussians holding NaN/Inf, which no viewer (nor ``read_ply``) accepts.
    """
    path = Path(path)
    g = g.detach().to(device="cpu", dtype=torch.float32)
    n, k = len(g), g.sh.shape[1]
    names = ply_property_names(g.sh_degree)
    # Fill one contiguous float table in place, then view it as records: a single copy per tensor.
    table = np.empty((n, len(names)), dtype="<f4")
    col = {name: j for j, name in enumerate(names)}
    table[:, col["x"] : col["x"] + 3] = g.means.numpy()
    table[:, col["nx"] : col["nx"] + 3] = 0.0  # normals: unused by 3DGS, expected by viewers
    sh = g.sh.numpy()
    table[:, col["f_dc_0"] : col["f_dc_0"] + 3] = sh[:, 0, :]
    for c in range(3 if k > 1 else 0):  # channel-major f_rest: all of channel 0, then 1, then 2
        first = col["f_rest_0"] + c * (k - 1)
        table[:, first : first + k - 1] = sh[:, 1:, c]
    table[:, col["opacity"]] = g.logit_opacities.numpy()
    table[:, col["scale_0"] : col["scale_0"] + 3] = g.log_scales.numpy()
    table[:, col["rot_0"] : col["rot_0"] + 4] = g.quats.numpy()
    if not np.isfinite(table).all():
        g.check_finite(f"write_ply({path})")  # names the offending tensor
    records = table.view(np.dtype([(name, "<f4") for name in names])).reshape(n)
    ply = plyfile.PlyData([plyfile.PlyElement.describe(records, "vertex")], text=False, byte_order="<")
    with atomic_write(path, "wb") as f:
        ply.write(f)

"""One reader or check per kind of input, used by every command that takes it (issue "Nothing lost").

Each turns a hostile or broken input into an :class:`InputError` (an ``M2MError``) that names the file or
field and says what to do, instead of a traceback, a silent wrong value or an exhausted machine:

- :func:`read_json`, :func:`read_yaml`: size limits, nesting depth, no YAML aliases (an alias bomb of a few
  kilobytes expands to gigabytes), the top level's type checked.
- :func:`read_image_rgb`: 8-bit RGB from 8- or 16-bit, grey, RGB or RGBA files (a 16-bit photo scaled, not
  clipped to white).
- :func:`check_intrinsics`, :func:`check_image_size`: finite intrinsics with positive focal lengths, an image
  size within limits; :func:`check_image_file`: an image file's size from its header, before it is decoded.
- :func:`check_mesh`: finite vertices, face indices in range, enough faces for a solid, a sane size.
- :func:`check_joints`: finite joint values, the robot's count, within its limits.

This module imports nothing else of ours but ``errors`` (the geometry layer uses it).
"""

from __future__ import annotations

import json
import math
import os
import re
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from .errors import M2MError

__all__ = [
    "MAX_IMAGE_SIDE",
    "InputError",
    "NAME_RE",
    "check_image_file",
    "check_image_size",
    "check_intrinsics",
    "check_joints",
    "check_mesh",
    "check_name",
    "read_image_rgb",
    "read_json",
    "read_yaml",
    "read_yaml_lines",
    "yaml_lines",
]

MAX_CONFIG_BYTES = 16 << 20  # JSON / YAML files the pipeline reads are kilobytes to a few megabytes
MAX_DEPTH = 64  # nesting of any config we write is under 10
MAX_IMAGE_SIDE = 16384  # pixels: a 16k x 16k RGB float image is already 3 GiB
NAME_RE = re.compile(r"^[A-Za-z][A-Za-z0-9_-]*$")  # an object's name: a folder name, a key, never a path
MAX_LOG_SCALE = 7.0  # a Gaussian wider than e^7 m (1.1 km) is no part of a tabletop scene (gaussians.ply checks)


class InputError(M2MError, ValueError):
    """An input file or value that cannot be used; the message names it and what to do."""


# ---- structured files -------------------------------------------------------------------------------
def _read_text(path: Path, what: str) -> str:
    if not path.is_file():
        raise InputError(f"{what} {path} not found" if not path.is_dir() else f"{what} {path} is a folder, not a file")
    size = path.stat().st_size
    if size > MAX_CONFIG_BYTES:
        raise InputError(f"{what} {path} is {size / 2**20:.0f} MiB; a {what} is at most {MAX_CONFIG_BYTES >> 20} MiB")
    try:
        return path.read_text(encoding="utf-8")
    except UnicodeDecodeError as e:
        raise InputError(f"{what} {path} is not UTF-8 text ({e.reason} at byte {e.start})") from None


def _depth(x: Any, limit: int, where: str) -> None:
    stack = [(x, 1)]
    while stack:
        v, d = stack.pop()
        if d > limit:
            raise InputError(f"{where}: nested deeper than {limit} levels")
        if isinstance(v, dict):
            stack.extend((c, d + 1) for c in v.values())
        elif isinstance(v, list):
            stack.extend((c, d + 1) for c in v)


def _top(data: Any, expect: type | None, path: Path, what: str) -> Any:
    if expect is not None and not isinstance(data, expect):
        name = {dict: "an object (mapping)", list: "a list"}.get(expect, expect.__name__)
        raise InputError(f"{what} {path} must hold {name} at the top level, got {type(data).__name__}")
    return data


def read_json(path: str | os.PathLike, what: str = "JSON file", expect: type | None = dict) -> Any:
    """The parsed JSON of ``path``; InputError for a missing, huge, non-JSON or too deeply nested file."""
    path = Path(path)
    text = _read_text(path, what)
    try:
        data = json.loads(text)
    except json.JSONDecodeError as e:
        raise InputError(f"{what} {path} is not valid JSON: {e.msg} (line {e.lineno}, column {e.colno})") from None
    except RecursionError:
        raise InputError(f"{what} {path}: nested deeper than Python can read; is it the right file?") from None
    _depth(data, MAX_DEPTH, f"{what} {path}")
    return _top(data, expect, path, what)


def read_yaml(path: str | os.PathLike, what: str = "YAML file", expect: type | None = dict) -> Any:
    """The parsed YAML of ``path`` with the safe loader; anchors and aliases are refused (nothing we write uses
    them, and a few kilobytes of nested aliases expand to gigabytes)."""
    return _checked(_parse_yaml(Path(path), what, lines=False)[0], Path(path), what, expect)


def read_yaml_lines(
    path: str | os.PathLike, what: str = "YAML file", expect: type | None = dict
) -> tuple[Any, dict[tuple[str | int, ...], int]]:
    """:func:`read_yaml` and, from the same parse, the 1-based line of every key and list item by its path of keys
    and indices (``("scene", "minutes")``, ``("objects", "names", 2)``; ``()`` is the first line): where a message
    about a value points. A key given twice in one mapping is an error (YAML readers keep the last silently)."""
    data, lines = _parse_yaml(Path(path), what, lines=True)
    return _checked(data, Path(path), what, expect), lines


def yaml_lines(path: str | os.PathLike, what: str = "YAML file") -> dict[tuple[str | int, ...], int]:
    """The lines of :func:`read_yaml_lines` alone."""
    return _parse_yaml(Path(path), what, lines=True)[1]


def _checked(data: Any, path: Path, what: str, expect: type | None) -> Any:
    if data is None:
        data = {} if expect is dict else data
    _depth(data, MAX_DEPTH, f"{what} {path}")
    return _top(data, expect, path, what)


def _parse_yaml(path: Path, what: str, lines: bool) -> tuple[Any, dict[tuple[str | int, ...], int]]:
    """The data of the YAML file (one parse with the alias-refusing safe loader) and, with ``lines``, its lines."""
    text = _read_text(path, what)
    try:
        loader = _no_alias_loader(path, what)(text)  # its reader refuses characters YAML does not allow (a NUL)
        try:
            node = loader.get_single_node()
            data = None if node is None else loader.construct_document(node)
        finally:
            loader.dispose()
    except yaml.YAMLError as e:
        raise InputError(f"{what} {path} is not valid YAML: {e}") from None
    except RecursionError:
        raise InputError(f"{what} {path}: nested deeper than Python can read") from None
    return data, (_node_lines(node, path, what) if lines else {})


def _no_alias_loader(path: Path, what: str) -> type:
    """A SafeLoader that refuses aliases, naming their line."""
    class _NoAliases(yaml.SafeLoader):
        def compose_node(self, parent, index):  # noqa: ANN001 - yaml's signature
            if self.check_event(yaml.AliasEvent):
                event = self.peek_event()
                raise InputError(f"{what} {path}: YAML aliases (*{event.anchor}) are not supported (line "
                                 f"{event.start_mark.line + 1}); write the values out")  # fmt: skip
            return super().compose_node(parent, index)

    return _NoAliases


def _node_lines(root: Any, path: Path, what: str) -> dict[tuple[str | int, ...], int]:
    lines: dict[tuple[str | int, ...], int] = {(): 1}
    stack = [((), root)]
    while stack:
        at, node = stack.pop()
        if isinstance(node, yaml.MappingNode):
            for key, value in node.value:
                here, line = (*at, str(key.value)), key.start_mark.line + 1
                if here in lines:  # YAML readers keep the last silently: a pasted second section would win
                    raise InputError(f"{what} {path}, line {line}: {'.'.join(map(str, here))} is given twice (also on "
                                     f"line {lines[here]}); keep one")  # fmt: skip
                lines[here] = line
                stack.append((here, value))
        elif isinstance(node, yaml.SequenceNode):
            for i, item in enumerate(node.value):
                lines[(*at, i)] = item.start_mark.line + 1
                stack.append(((*at, i), item))
    return lines


# ---- images -----------------------------------------------------------------------------------------
def read_image_rgb(path: str | os.PathLike, what: str = "image") -> np.ndarray:
    """uint8 [H,W,3] RGB of an 8- or 16-bit grey, RGB or RGBA image (16-bit values scaled by 255/65535)."""
    import cv2

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{what} {path} not found")
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None or img.size == 0:
        raise InputError(f"{what} {path} cannot be read as an image (PNG, JPEG, ...)")
    if img.dtype == np.uint16:
        img = (img.astype(np.float32) * (255.0 / 65535.0) + 0.5).astype(np.uint8)
    elif img.dtype != np.uint8:
        raise InputError(f"{what} {path}: {img.dtype} pixels are not supported; save it as 8- or 16-bit")
    if img.ndim == 2:
        return np.repeat(img[:, :, None], 3, axis=2)
    if img.shape[2] == 4:
        img = img[:, :, :3]
    return np.ascontiguousarray(img[:, :, ::-1])  # BGR -> RGB


# ---- values -------------------------------------------------------------------------------------------
def check_intrinsics(K: Any, where: str) -> np.ndarray:
    """K [3,3] float64 of a pinhole camera: finite, ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]`` with fx, fy > 0."""
    try:
        K = np.asarray(K, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{where}: K must be 3x3 numbers") from None
    if K.shape != (3, 3) or not np.isfinite(K).all():
        raise InputError(f"{where}: K must be 3x3 finite numbers, got shape {K.shape}")
    if not (K[0, 0] > 0 and K[1, 1] > 0):
        raise InputError(f"{where}: K: focal lengths must be positive, got fx={K[0, 0]:g} fy={K[1, 1]:g}")
    if abs(K[1, 0]) > 1e-9 or np.abs(K[2] - [0.0, 0.0, 1.0]).max() > 1e-9:
        raise InputError(f"{where}: K must be [[fx, s, cx], [0, fy, cy], [0, 0, 1]], got {K.tolist()}")
    return K


def check_image_size(value: Any, where: str, name: str) -> int:
    """An image side in pixels: a whole number in 1..MAX_IMAGE_SIDE."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise InputError(f"{where}: {name} must be a positive integer, got {value!r}")
    if not math.isfinite(float(value)) or not float(value).is_integer() or value <= 0:
        raise InputError(f"{where}: {name} must be a positive integer, got {value!r}")
    if value > MAX_IMAGE_SIDE:
        raise InputError(f"{where}: {name} {int(value)} is more than {MAX_IMAGE_SIDE} pixels")
    return int(value)


def check_name(name: Any, where: str) -> str:
    """An object's name (it names folders: ``objects/<name>/``): letters, digits, '_' or '-', starting with a letter."""
    if not isinstance(name, str) or not NAME_RE.match(name):
        raise InputError(f"{where}: use letters, digits, '_' or '-', starting with a letter (it names a folder)")
    return name


def check_image_file(path: str | os.PathLike, what: str = "image") -> None:
    """An image file's size from its header (nothing decoded): InputError when it is not an image or is larger than
    MAX_IMAGE_SIDE a side (decoding 8 blank 17000 x 13000 PNGs took 2.3 GB)."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            size = "{}x{} pixels".format(*im.size) if max(im.size) > MAX_IMAGE_SIDE else None
    except Image.DecompressionBombError:  # PIL refuses over ~180 megapixels without saying the size
        size = "over 180 megapixels"
    except (OSError, UnidentifiedImageError):
        raise InputError(f"{what} {path}: not a readable image; remove or replace it") from None
    if size is not None:
        raise InputError(f"{what} {path} is {size}, more than {MAX_IMAGE_SIDE} pixels a side; resize it (SfM and "
                         "training use 2000 px or less)")  # fmt: skip


def check_mesh(vertices: Any, faces: Any, where: str, max_extent: float = 10.0) -> None:
    """Finite vertices, faces indexing them, at least a tetrahedron's worth (4) of faces, extent <= max_extent m."""
    V, F = np.asarray(vertices), np.asarray(faces)
    if V.ndim != 2 or V.shape[1:] != (3,) or len(V) < 4:
        raise InputError(f"{where}: a mesh needs at least 4 vertices (x, y, z), got {V.shape}")
    if not np.isfinite(V).all():
        raise InputError(f"{where}: a vertex is not finite")
    if F.ndim != 2 or F.shape[1:] != (3,) or len(F) < 4:
        raise InputError(f"{where}: a solid needs at least 4 triangles, got {F.shape[0] if F.ndim == 2 else 0}")
    if F.min() < 0 or F.max() >= len(V):
        raise InputError(f"{where}: a face refers to vertex {int(F.max() if F.max() >= len(V) else F.min())} of "
                         f"{len(V)}")  # fmt: skip
    extent = float(np.ptp(V, axis=0).max())
    if not 0 < extent <= max_extent:
        raise InputError(f"{where}: the mesh is {extent:.3g} m across; expected an object of up to {max_extent} m "
                         "(check its units: metres)")  # fmt: skip


def check_joints(q: Any, names: tuple[str, ...], limits: np.ndarray | None, where: str) -> np.ndarray:
    """q [len(names)] float64: finite, one value per joint, within ``limits`` [n,2] (rad / m) when given."""
    try:
        q = np.asarray(q, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise InputError(f"{where}: joint values must be numbers, got {q!r}") from None
    if len(q) != len(names):
        raise InputError(f"{where}: {len(q)} joint value(s) for the robot's {len(names)} joints ({', '.join(names)})")
    if not np.isfinite(q).all():
        raise InputError(f"{where}: joint values must be finite, got {q.tolist()}")
    if limits is not None:
        lo, hi = limits[:, 0], limits[:, 1]
        out = np.nonzero((q < lo - 1e-6) | (q > hi + 1e-6))[0]
        if len(out):
            i = int(out[0])
            raise InputError(f"{where}: joint {names[i]} = {q[i]:.4g} is outside its limits "
                             f"[{lo[i]:.4g}, {hi[i]:.4g}]")  # fmt: skip
    return q

"""Fuzz the readers of user files with hypothesis: PLY, world.yaml, transforms.json, COLMAP text models.

Every input either parses or raises an ``M2MError`` (a clear error naming the file); anything else (a traceback)
fails the run. Run as a script (``tests/test_fuzz.py`` does, in a child process, to measure its peak memory):

    python tests/fuzz_readers.py EXAMPLES WORKDIR
"""

from __future__ import annotations

import json
import shutil
import sys
import tempfile
from pathlib import Path

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mirage2matter.errors import M2MError

SETTINGS = {"deadline": None, "suppress_health_check": list(HealthCheck), "derandomize": True}

# JSON-like values, nested, with the keys our files use among random ones
OUR_KEYS = ["robot", "cameras", "objects", "lights", "placement", "K", "width", "height", "frames", "file_path",
            "transform_matrix", "fl_x", "w", "h", "mesh", "gaussians", "home", "name", "mount", "T_mount_cam", "scale",
            "rotation", "translation", "dir", "randomize"]  # fmt: skip
KEYS = st.sampled_from(OUR_KEYS) | st.text(max_size=8)
SCALARS = st.none() | st.booleans() | st.integers(-(10**12), 10**12) | st.floats() | st.text(max_size=12)
VALUES = st.recursive(SCALARS, lambda c: st.lists(c, max_size=5) | st.dictionaries(KEYS, c, max_size=6), max_leaves=40)


def _mutations(seed: bytes) -> st.SearchStrategy[bytes]:
    """``seed`` with a few bytes overwritten, cut short or spliced."""

    def mutate(args) -> bytes:
        edits, cut = args
        data = bytearray(seed)
        for pos, val in edits:
            if data:
                data[pos % len(data)] = val
        return bytes(data[: cut % (len(data) + 1)] if cut else data)

    return st.tuples(st.lists(st.tuples(st.integers(0, 10**9), st.integers(0, 255)), max_size=20),
                     st.integers(0, 10**9) | st.none()).map(mutate)  # fmt: skip


def _expect_clear(fn, *args) -> None:
    try:
        fn(*args)
    except M2MError:
        pass  # a clear error


def fuzz(examples: int, work: Path) -> None:
    import numpy as np
    import yaml

    from fixtures.gaussians import random_gaussians
    from mirage2matter.gaussians.ply import read_ply, write_ply
    from mirage2matter.geometry.camera import load_transforms_json
    from mirage2matter.sfm.importers import import_colmap_model
    from mirage2matter.world.config import read_world

    work.mkdir(parents=True, exist_ok=True)
    ok_ply = work / "ok.ply"
    write_ply(ok_ply, random_gaussians(20, 1))
    ply_seed = ok_ply.read_bytes()

    @settings(max_examples=examples, **SETTINGS)
    @given(st.binary(max_size=4096) | _mutations(ply_seed))
    def ply(data: bytes) -> None:
        p = work / "f.ply"
        p.write_bytes(data)
        _expect_clear(read_ply, p)

    world_dir = work / "world"
    world_dir.mkdir(exist_ok=True)
    head = {"mount": "base", "T_mount_cam": np.eye(4).tolist(), "K": [[500, 0, 320], [0, 500, 240], [0, 0, 1]],
            "width": 640, "height": 480}  # fmt: skip
    seed = {"version": 1, "cameras": {"head": head}, "lights": [{"dir": [0, 0, -1]}]}
    yaml_seed = yaml.safe_dump({**seed, "randomize": {"articulated": True}}).encode()

    @settings(max_examples=examples, **SETTINGS)
    @given(VALUES.map(lambda v: yaml.safe_dump(v).encode()) | _mutations(yaml_seed) | st.binary(max_size=512))
    def world(data: bytes) -> None:
        p = world_dir / "world.yaml"
        p.write_bytes(data)
        _expect_clear(read_world, p)

    @settings(max_examples=examples, **SETTINGS)
    @given(VALUES.map(lambda v: json.dumps(v).encode()) | st.binary(max_size=512))
    def transforms(data: bytes) -> None:
        p = work / "transforms.json"
        p.write_bytes(data)
        _expect_clear(load_transforms_json, p)

    images = work / "images"
    images.mkdir(exist_ok=True)
    lines = st.lists(st.text(alphabet="0123456789.- abcPINHOLE/\\n#", max_size=60), max_size=6).map("\n".join)

    @settings(max_examples=max(10, examples // 4), **SETTINGS)
    @given(lines, lines, lines)
    def colmap(cameras: str, image_lines: str, points: str) -> None:
        model = work / "model"
        shutil.rmtree(model, ignore_errors=True)
        model.mkdir()
        (model / "cameras.txt").write_text(cameras)
        (model / "images.txt").write_text(image_lines)
        (model / "points3D.txt").write_text(points)
        _expect_clear(import_colmap_model, model, images, work / "ws" / "capture", work / "ws" / "sfm")

    for fn in (ply, world, transforms, colmap):
        fn()
        print(f"{fn.__name__}: ok", flush=True)
    import resource

    print(f"peak_rss_mb {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f}", flush=True)


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).parent))
    with tempfile.TemporaryDirectory() as tmp:
        fuzz(int(sys.argv[1]), Path(sys.argv[2]) if len(sys.argv) > 2 else Path(tmp))

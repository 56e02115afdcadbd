"""Hostile and broken inputs, as a user (or an attacker) might hand them over: every one ends with exit status 2
and a message naming the file or field, without a traceback, and leaves every file under the test's folder
(the workspace and its surroundings) byte-identical: nothing half-written, nothing written outside.

Each case is a setup (files in ``tmp``) and the ``m2m`` arguments; ``CASES`` drives one test per case."""

from __future__ import annotations

import hashlib
import json
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh
import yaml

from fixtures import SAMPLE, sample_present
from fixtures.gaussians import random_gaussians
from mirage2matter.cli import main
from mirage2matter.gaussians.ply import write_ply

pytestmark = pytest.mark.skipif(not sample_present(), reason=f"the bundled sample is not at {SAMPLE}")


def tree_hash(root: Path) -> dict[str, str]:
    """{relative path: sha256} of every file below ``root`` (folders themselves carry no data)."""
    return {
        str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


@dataclass
class Case:
    name: str
    setup: Callable[[Path, dict], list[str]]  # (tmp, shared fixtures) -> m2m arguments
    message: str  # a regex the error must match


# ---- shared inputs ---------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def world_ws(sample_world_ws) -> Path:
    return sample_world_ws(gaussians_per_object=4000, scene_density_per_m2=8000.0, max_collision_parts=4)


@pytest.fixture(scope="module")
def transforms(tmp_path_factory) -> Path:
    """A small transforms.json capture of the sample (8 frames at half resolution) and a workspace imported
    from it (capture/ + sfm/)."""
    from mirage2matter.sample.transforms import write_sample_transforms

    root = tmp_path_factory.mktemp("imported")
    tf = write_sample_transforms(SAMPLE, root / "data", every=90, scale=0.5)
    assert main(["sfm", "-w", str(root / "ws"), "--from-transforms", str(tf)]) == 0
    return tf


def _world_copy(tmp: Path, fx: dict) -> Path:
    ws = tmp / "ws"
    shutil.copytree(fx["world_ws"], ws, symlinks=True)
    return ws


def _edit_world_yaml(fn) -> Callable[[Path, dict], list[str]]:
    def setup(tmp: Path, fx: dict) -> list[str]:
        ws = _world_copy(tmp, fx)
        path = ws / "world" / "world.yaml"
        data = yaml.safe_load(path.read_text())
        text = fn(data)
        path.write_text(text if isinstance(text, str) else yaml.safe_dump(data))
        return ["world", "check", "-w", str(ws)]

    return setup


def _insert(make_mesh=None, make_ply=None) -> Callable[[Path, dict], list[str]]:
    def setup(tmp: Path, fx: dict) -> list[str]:
        ws = _world_copy(tmp, fx)
        mesh = tmp / "asset" / "thing.obj"
        mesh.parent.mkdir()
        if make_mesh is None:  # a 5 cm cube resting on the table
            trimesh.creation.box((0.05, 0.05, 0.05), trimesh.transformations.translation_matrix([0, 0, 0.025])).export(
                mesh
            )
        else:
            make_mesh(mesh)
        ply = tmp / "asset" / "thing.ply"
        write_ply(ply, make_ply() if make_ply is not None else random_gaussians(200, 1, extent=0.02))
        return ["world", "insert", "-w", str(ws), "--name", "thing", "--gaussians", str(ply), "--mesh", str(mesh),
                "--to", "0.45,-0.25,0.0"]  # fmt: skip

    return setup


def _raw_ply(tmp: Path, fx: dict, mutate) -> list[str]:
    g = random_gaussians(100, 1, extent=0.02)
    mutate(g)
    return _insert(make_ply=lambda: g)(tmp, fx)


def _import_scale(scale: float) -> Callable[[Path, dict], list[str]]:
    def setup(tmp: Path, fx: dict) -> list[str]:
        from mirage2matter.gaussians.ply import read_ply
        from mirage2matter.gaussians.transform import apply_sim3
        from mirage2matter.geometry.sim3 import Sim3
        from mirage2matter.world import load_world

        ws = _world_copy(tmp, fx)
        cfg = load_world(ws / "world")
        local = read_ply(cfg.object("banana").part.gaussians)
        moved = Sim3(scale, np.eye(3), np.array([0.45, 0.1, 0.0]))
        write_ply(tmp / "moved.ply", apply_sim3(local, moved))
        return ["world", "import-placement", "-w", str(ws), "--name", "banana", "--ply", str(tmp / "moved.ply")]

    return setup


def _colmap_escape(tmp: Path, fx: dict) -> list[str]:
    """A COLMAP text model whose image names climb out of the images folder (and so out of capture/)."""
    from PIL import Image

    images = tmp / "data" / "deep" / "images"
    images.mkdir(parents=True)
    for name in ("a.png", "../../OUT.png"):
        (images / name).parent.mkdir(parents=True, exist_ok=True)
        Image.fromarray(np.zeros((48, 64, 3), np.uint8)).save(images / name)
    model = tmp / "data" / "model"
    model.mkdir()
    (model / "cameras.txt").write_text("1 PINHOLE 64 48 50 50 32 24\n")
    (model / "images.txt").write_text("1 1 0 0 0 0 0 0 1 a.png\n\n2 1 0 0 0 0.1 0 0 1 ../../OUT.png\n\n")
    (model / "points3D.txt").write_text("")
    return ["sfm", "-w", str(tmp / "ws"), "--from-colmap", str(model), "--images", str(images)]


def _transforms_wrong_size(tmp: Path, fx: dict) -> list[str]:
    tf = fx["transforms"]
    ws = tmp / "ws"
    shutil.copytree(tf.parent.parent / "ws", ws)
    data = json.loads(tf.read_text())
    data["w"], data["h"] = 2 * data["w"], 2 * data["h"]
    bad = tf.parent / f"bad_{tmp.name}.json"
    bad.write_text(json.dumps(data))
    return ["sfm", "-w", str(ws), "--from-transforms", str(bad)]


def _corrupt_video(tmp: Path, fx: dict) -> list[str]:
    data = bytearray((SAMPLE / "scene.mp4").read_bytes())
    rng = np.random.default_rng(0)
    for i in rng.integers(len(data) // 10, len(data), 3000):
        data[i] = int(rng.integers(256))
    (tmp / "damaged.mp4").write_bytes(bytes(data))
    return ["capture", str(tmp / "damaged.mp4"), "-w", str(tmp / "ws")]


def _handeye_missing_joints(tmp: Path, fx: dict) -> list[str]:
    he = SAMPLE / "handeye"
    data = json.loads((he / "joints.json").read_text())
    data["views"][3]["joints"] = data["views"][3]["joints"][:2]  # 2 of 9
    (tmp / "joints.json").write_text(json.dumps(data))
    return ["calibrate-handeye", "-w", str(tmp / "ws"), "--images", str(he / "images"), "--joints",
            str(tmp / "joints.json"), "--board", str(he / "board.json"), "--intrinsics",
            str(SAMPLE / "ground_truth.json")]  # fmt: skip


def _render_camera(camera_text: str) -> Callable[[Path, dict], list[str]]:
    def setup(tmp: Path, fx: dict) -> list[str]:
        write_ply(tmp / "g.ply", random_gaussians(50, 0))
        (tmp / "cam.json").write_text(camera_text)
        return ["render", str(tmp / "g.ply"), "--camera", str(tmp / "cam.json"), "--out", str(tmp / "out.png")]

    return setup


def _empty_ply(tmp: Path, fx: dict) -> list[str]:
    write_ply(tmp / "g.ply", random_gaussians(50, 0).select(torch.zeros(50, dtype=torch.bool)))
    (tmp / "cam.json").write_text(_camera(100, 100))
    return ["render", str(tmp / "g.ply"), "--camera", str(tmp / "cam.json"), "--out", str(tmp / "out.png")]


def _camera(width: int, height: int) -> str:
    return json.dumps({"width": width, "height": height, "K": [[100, 0, 50], [0, 100, 50], [0, 0, 1]],
                       "T_world_cam": np.eye(4).tolist()})  # fmt: skip


def _bad_pipeline_yaml(text: str, command: str = "train-scene") -> Callable[[Path, dict], list[str]]:
    def setup(tmp: Path, fx: dict) -> list[str]:
        ws = tmp / "ws"
        ws.mkdir()
        (ws / "m2m.yaml").write_text(text)
        return [command, "-w", str(ws)]

    return setup


def _alias_bomb() -> str:
    lines = ['a: &a ["x","x","x","x","x","x","x","x","x"]']
    for k in range(1, 9):
        prev = chr(ord("a") + k - 1)
        cur = chr(ord("a") + k)
        lines.append(f"{cur}: &{cur} [{', '.join([f'*{prev}'] * 9)}]")
    return "\n".join(lines) + "\n"


def _flat_mesh(path: Path) -> None:
    trimesh.Trimesh([[0, 0, 0], [0.05, 0, 0], [0, 0.05, 0], [0.05, 0.05, 0]], [[0, 1, 2], [1, 3, 2], [0, 2, 1],
                                                                             [1, 2, 3]]).export(path)  # fmt: skip


def _open_mesh(path: Path) -> None:
    box = trimesh.creation.box((0.05, 0.05, 0.05))
    trimesh.Trimesh(box.vertices, box.faces[:6]).export(path)  # half the faces: a shell with a big opening


def _home(v):
    def fn(d):
        d["robot"]["home"] = v

    return fn


def _set(fn):
    def apply(d):
        fn(d)

    return apply


# ---- issue 65: values that are well-formed but make no sense -------------------------------------------------
def _intrinsics(text: str, name: str = "cam.json") -> Callable[[Path, dict], list[str]]:
    def setup(tmp: Path, fx: dict) -> list[str]:
        (tmp / name).write_text(text)
        return ["intrinsics", str(tmp / name)]

    return setup


def _K(fx: float = 500, fy: float = 500, cx: float = 320, cy: float = 240, **dist: float) -> str:
    return json.dumps({"K": [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], "width": 640, "height": 480, "distortion": dist})


def _truncated_xml() -> str:
    return ('<?xml version="1.0"?>\n<opencv_storage>\n<image_width>640</image_width>\n<camera_matrix type_id="opencv-'
            'matrix">\n  <rows>3</rows>\n  <cols>3</cols>\n  <dt>d</dt>\n  <data>\n    500. 0. 320. 0. 500.')


def _panda_spec(edit) -> Callable[[Path, dict], list[str]]:
    def setup(tmp: Path, fx: dict) -> list[str]:
        from mirage2matter.robots import get_robot

        data = yaml.safe_load(Path(get_robot("panda").source).read_text())
        edit(data)
        (tmp / "robot.yaml").write_text(yaml.safe_dump(data))
        return ["robot", str(tmp / "robot.yaml")]

    return setup


def _backwards_mjcf(tmp: Path, fx: dict) -> list[str]:
    (tmp / "arm.xml").write_text(
        '<mujoco><worldbody><body name="link1"><joint name="j1" type="hinge" range="1.76 -1.76"/><geom size=".05"/>'
        '<body name="link2" pos="0 0 .3"><joint name="j2" type="hinge" range="-1 1"/><geom size=".05"/></body>'
        "</body></worldbody></mujoco>")  # fmt: skip
    (tmp / "robot.yaml").write_text("name: arm\nmodel: arm.xml\narm: {joints: [j1, j2], home: [0, 0]}\n")
    return ["robot", str(tmp / "robot.yaml")]


def _big_images(tmp: Path, fx: dict) -> list[str]:
    from PIL import Image

    (tmp / "images").mkdir()  # the header says the size: a 17000 x 13000 image is refused as this one is
    Image.new("L", (17000, 8)).save(tmp / "images" / "0.png")
    return ["capture", str(tmp / "images"), "-w", str(tmp / "ws")]


def _handeye_view_off(tmp: Path, fx: dict) -> list[str]:
    he = SAMPLE / "handeye"
    data = json.loads((he / "joints.json").read_text())
    data["views"][5]["joints"][1] += 0.5  # one view's shoulder logged 0.5 rad off
    (tmp / "joints.json").write_text(json.dumps(data))
    return ["calibrate-handeye", "-w", str(tmp / "ws"), "--images", str(he / "images"), "--joints",
            str(tmp / "joints.json"), "--board", str(he / "board.json"), "--intrinsics",
            str(SAMPLE / "ground_truth.json")]  # fmt: skip


def _sfm_two_sources(tmp: Path, fx: dict) -> list[str]:
    ws = tmp / "ws"
    shutil.copytree(fx["transforms"].parent.parent / "ws", ws)
    (tmp / "cam.json").write_text(_K())
    return ["sfm", "-w", str(ws), "--from-transforms", str(fx["transforms"]), "--intrinsics", str(tmp / "cam.json")]


def _dataset(edit) -> Callable[[Path, dict], list[str]]:
    def setup(tmp: Path, fx: dict) -> list[str]:
        from fixtures.policy_datasets import build_dataset, spec_for

        root = tmp / "ds"
        build_dataset(root, spec_for(), seeds=(0,), length=4)
        info = root / "meta" / "info.json"
        data = json.loads(info.read_text())
        edit(root, data)
        info.write_text(json.dumps(data))
        return ["validate", str(root)]

    return setup


def _extra_column(root: Path, info: dict) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    path = next(root.glob("data/**/*.parquet"))
    table = pq.read_table(path)
    pq.write_table(table.append_column("secret", pa.array([1.0] * len(table))), path)


CASES = [
    Case("sfm --from-colmap: an image name that climbs out of the images folder", _colmap_escape, "stay inside"),
    Case("sfm --from-transforms: images of another size than the file says (capture/ kept)",
         _transforms_wrong_size, "transforms|size|images"),  # fmt: skip
    Case("capture: a video damaged by 3,000 flipped bytes", _corrupt_video,
         r"only \d+ of its 720 frames decode|decoding failed at frame \d+.*damaged from there"),
    Case("calibrate-handeye: a view with 2 of 9 joint values", _handeye_missing_joints, r"2 joint value"),
    Case("world.yaml: NaN in robot.home", _edit_world_yaml(_home([float("nan")] * 7)), r"robot\.home.*finite"),
    Case("world.yaml: robot.home is a number", _edit_world_yaml(_home(5)), r"robot\.home"),
    Case("world.yaml: robot.home out of the joint limits", _edit_world_yaml(_home([0, 0, 0, 3.5, 0, 1.5, 0])),
         r"robot\.home: joint joint4 .* outside its limits"),  # fmt: skip
    Case("world.yaml: a zero camera matrix", _edit_world_yaml(_set(lambda d: d["cameras"]["head"].update(
        K=[[0, 0, 0], [0, 0, 0], [0, 0, 1]]))), r"cameras\.head\.K.*positive"),  # fmt: skip
    Case("world.yaml: a camera 1e9 pixels wide", _edit_world_yaml(_set(lambda d: d["cameras"]["head"].update(
        width=10**9))), r"cameras\.head\.width.* more than 16384"),  # fmt: skip
    Case("world.yaml: cameras as a list", _edit_world_yaml(_set(lambda d: d.update(cameras=[1, 2]))),
         r"cameras: expected a mapping"),  # fmt: skip
    Case('world.yaml: randomize.articulated: "no"', _edit_world_yaml(_set(lambda d: d["randomize"].update(
        articulated="no"))), r"randomize\.articulated: expected true or false"),  # fmt: skip
    Case("world.yaml: an object 1e6 m away", _edit_world_yaml(_set(lambda d: d["objects"][0]["placement"].update(
        translation=[1e6, 0, 0]))), r"banana\.placement.*more than 10(\.0)? m"),  # fmt: skip
    Case("world.yaml: a light without dir", _edit_world_yaml(_set(lambda d: d["lights"][0].pop("dir"))),
         r"lights\[0\]: missing 'dir'"),  # fmt: skip
    Case("world.yaml: an asset outside the workspace", _edit_world_yaml(_set(lambda d: d["objects"][0].update(
        mesh="/etc/passwd"))), r"outside the workspace"),  # fmt: skip
    Case("world.yaml: a 3 KB alias bomb", _edit_world_yaml(lambda d: _alias_bomb()), r"aliases .* not supported"),
    Case("world insert: a one-triangle mesh", _insert(lambda p: trimesh.Trimesh(
        [[0, 0, 0], [0.05, 0, 0], [0, 0.05, 0]], [[0, 1, 2]]).export(p)), r"at least 4"),  # fmt: skip
    Case("world insert: a face pointing at vertex 99 of 4", _insert(lambda p: p.write_text(
        "v 0 0 0\nv 0.05 0 0\nv 0 0.05 0\nv 0 0 0.05\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 99\n")),
        r"thing\.obj"),  # fmt: skip
    Case("world insert: a flat (zero-volume) mesh", _insert(_flat_mesh), r"watertight|volume|closed"),
    Case("world insert: an open shell", _insert(_open_mesh), r"watertight|closed"),
    Case("world insert: a PLY without Gaussians", _insert(make_ply=lambda: random_gaussians(1, 1).select(
        torch.zeros(1, dtype=torch.bool))), r"no Gaussians"),  # fmt: skip
    Case("world insert: zero quaternions", lambda t, f: _raw_ply(t, f, lambda g: g.quats.zero_()),
         r"zero rotation"),  # fmt: skip
    Case("world insert: a Gaussian of log-scale 60", lambda t, f: _raw_ply(t, f, lambda g: g.log_scales[0].fill_(60)),
         r"log-scale 60"),  # fmt: skip
    Case("world import-placement: scale x1e-9", _import_scale(1e-9), r"size by x1e-09|do not span a solid"),
    Case("world import-placement: scale x1000", _import_scale(1e3), r"size by x1e\+03"),
    Case("world import-placement: scale x10 without --allow-scale", _import_scale(10.0), r"--allow-scale"),
    Case("render: a camera file nested 10^5 levels deep", _render_camera("[" * 100000 + "]" * 100000),
         r"nested deeper"),  # fmt: skip
    Case("render: a 200000 x 200000 camera", _render_camera(_camera(200000, 200000)), r"more than 16384"),
    Case("render: a PLY with no Gaussians", _empty_ply, r"g\.ply: holds no Gaussians"),
    Case("m2m.yaml: an unknown setting", _bad_pipeline_yaml("scene:\n  minuets: 3\n"), r"unknown setting.*minuets"),
    Case("m2m.yaml: a wrong type", _bad_pipeline_yaml("scene:\n  minutes: soon\n"),
         r"scene\.minutes: expected a number"),  # fmt: skip
    Case("m2m.yaml: an alias bomb", _bad_pipeline_yaml(_alias_bomb()), r"aliases .* not supported"),
    # issue 65
    Case("m2m.yaml: min_parallax_px: .nan", _bad_pipeline_yaml("capture:\n  min_parallax_px: .nan\n"),
         r"line 2: capture\.min_parallax_px: nan is not a finite number; allowed: a number in \[0, 640\]"),
    Case("m2m.yaml: jpeg_quality: 500", _bad_pipeline_yaml("capture:\n  jpeg_quality: 500\n"),
         r"capture\.jpeg_quality: 500 is out of range; allowed: an integer in \[1, 100\]"),
    Case("m2m.yaml: scene.minutes: -.inf", _bad_pipeline_yaml("scene:\n  minutes: -.inf\n"),
         r"scene\.minutes: -inf is not a finite number"),
    Case("m2m.yaml: randomize.x backwards", _bad_pipeline_yaml("world:\n  randomize:\n    x: [0.6, 0.3]\n"),
         r"world\.randomize\.x: \[0\.6, 0\.3\] has its first value above"),
    Case("m2m.yaml: an object named ../evil", _bad_pipeline_yaml("objects:\n  names: [../evil]\n", "objects"),
         r"'\.\./evil'.*letters, digits"),
    Case("flag: train-scene --minutes nan", lambda t, f: ["train-scene", "-w", str(t / "ws"), "--minutes", "nan"],
         r"--minutes: nan is not a finite number"),
    Case("flag: generate --episodes 10**30", lambda t, f: ["generate", "-w", str(t / "ws"), "--task", "grasp banana",
         "--episodes", str(10**30)], r"--episodes: 10{30} is out of range"),  # fmt: skip
    Case("intrinsics: principal point x = 5000 in a 640-wide image", _intrinsics(_K(cx=5000)),
         r"cam\.json: the principal point \(5000, 240\) lies outside the 640x480 image"),
    Case("intrinsics: k1 = 50, k2 = -300", _intrinsics(_K(k1=50, k2=-300)), r"cam\.json: its distortion .* turns back"),
    Case("intrinsics: fy = 100 fx", _intrinsics(_K(fy=50000)), r"cam\.json: fx / fy = 0\.01"),
    Case("intrinsics: fx = 1 (a 175 deg field of view)", _intrinsics(_K(fx=10, fy=10)), r"field of view"),
    Case("intrinsics: a truncated OpenCV XML", _intrinsics(_truncated_xml(), "cal.xml"),
         r"cal\.xml: OpenCV cannot parse this file"),  # fmt: skip
    Case("robot spec: a tool centre in millimetres", _panda_spec(lambda d: d["end_effector"].update(
        tcp=[0, 0, 103.4])), r"end_effector\.tcp.*103 m from hand.*units: mm"),  # fmt: skip
    Case("robot spec: a wrist camera 70 m from its link", _panda_spec(lambda d: d["cameras"]["wrist"].update(
        eye=[70, 0, 0])), r"cameras\.wrist\.eye.*70 m"),  # fmt: skip
    Case("robot spec: units: inch", _panda_spec(lambda d: d.update(units="inch")), r"units.*m .*or mm"),
    Case("robot model: an MJCF range written backwards", _backwards_mjcf, r"joint j1: range 1\.76 -1\.76 .*backwards"),
    Case("capture: images larger than 16384 px", _big_images, r"0\.png is 17000x8 pixels, more than 16384"),
    Case("calibrate-handeye: one of 18 views 0.5 rad off", _handeye_view_off, r"view 0005\.png disagrees with"),
    Case("sfm: --from-transforms and --intrinsics together", _sfm_two_sources,
         r"intrinsics and from_transforms are both given"),  # fmt: skip
    Case("validate: a column info.json does not declare", _dataset(_extra_column), r"secret not declared"),
    Case("validate: chunks_size 0", _dataset(lambda r, d: d.update(chunks_size=0)), r"chunks_size = 0"),
    Case("validate: robot_type 5", _dataset(lambda r, d: d.update(robot_type=5)), r"robot_type = 5 is not text"),
]


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_hostile_input_is_a_clear_error_and_changes_nothing(case, tmp_path, world_ws, transforms, capsys):
    fx = {"world_ws": world_ws, "transforms": transforms}
    argv = case.setup(tmp_path, fx)
    watched = [tmp_path, transforms.parent]  # the case's folder and the shared inputs beside it
    before = [tree_hash(p) for p in watched]
    capsys.readouterr()
    rc = main(argv)
    err = capsys.readouterr().err
    assert rc == 2, f"exit {rc}; stderr: {err[-2000:]}"
    assert err.startswith("m2m: error: ") and "Traceback" not in err, err
    import re

    assert re.search(case.message, err), f"{case.message!r} not in {err!r}"
    after = [tree_hash(p) for p in watched]
    for b, a, where in zip(before, after, watched, strict=True):
        changed = sorted(k for k in set(b) | set(a) if b.get(k) != a.get(k))
        assert not changed, f"{where}: files changed by a failing command: {changed[:10]}"

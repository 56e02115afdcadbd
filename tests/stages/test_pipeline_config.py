"""A workspace's m2m.yaml: written with every field under its doc, read back to the same settings, every bad value
named with its line; which stages a pipeline run takes, why it skips the others, and a failing stage named."""

from __future__ import annotations

import dataclasses
import json
import re
import shutil
from dataclasses import replace
from pathlib import Path

import pytest

from fixtures import SAMPLE
from mirage2matter.cli import main
from mirage2matter.configs import ConfigError, _hints, _is_config, _unwrap_optional, field_docs
from mirage2matter.inputs import InputError, yaml_lines
from mirage2matter.stages.pipeline import PipelineConfig, PipelineError, SettingsFile, plan_run, run_pipeline
from mirage2matter.workspace import Workspace

SAMPLE_YAML = SAMPLE / "m2m.yaml"


def _leaves(cls: type, at: tuple = ()):
    """(key path, doc) of every field, nested Configs walked (their own key too); a section's field that is the
    whole pipeline's (the robot) is written once, at the top."""
    docs, hints = field_docs(cls), _hints(cls)
    for f in dataclasses.fields(cls):
        if at and f.metadata.get("shared"):
            continue
        yield (*at, f.name), docs.get(f.name)
        tp, _ = _unwrap_optional(hints[f.name])
        if _is_config(tp):
            yield from _leaves(tp, (*at, f.name))


def _every_kind(tmp: Path) -> PipelineConfig:
    """The sample's settings with a field of every kind away from its default (mappings, nested lists, tuples)."""
    cfg = PipelineConfig.load(SAMPLE_YAML)
    objects = replace(cfg.objects, mesh={"banana": tmp / "ws" / "inputs" / "banana.obj"}, density={"banana": 320.0},
                      keypoints={"banana": [((0.0, 0.0, 0.0), (0.4, 0.1, 0.02)), ((0.01, 0, 0), (0.41, 0.1, 0.02))]},
                      prompts=["banana@frame_000001.jpg:box=1,2,30,40"])  # fmt: skip
    return replace(cfg, objects=objects, world=replace(cfg.world, buttons=("button",), max_mm=2.5),
                   sfm=replace(cfg.sfm, matching="sequential"), scene=replace(cfg.scene, sh_degree=1))  # fmt: skip


def test_saved_settings_read_back_the_same_with_every_field_under_its_doc(tmp_path, monkeypatch):
    cfg = _every_kind(tmp_path)
    monkeypatch.chdir(tmp_path)
    cfg = replace(cfg, head_view=replace(cfg.head_view, photo=Path("head.png")))  # relative: the current folder
    path = cfg.save(tmp_path / "ws" / "m2m.yaml")
    loaded = PipelineConfig.load(path)
    assert loaded == replace(cfg, head_view=replace(cfg.head_view, photo=tmp_path / "head.png"))
    text = path.read_text()
    # inside the workspace: relative to it; outside: absolute (a relative command-line path is the current folder's)
    assert "  mesh: {banana: inputs/banana.obj}\n" in text and f"  photo: {tmp_path / 'head.png'}\n" in text
    assert f"  source: {(SAMPLE / 'scene.mp4').resolve()}\n" in text
    lines, where = text.splitlines(), yaml_lines(path)
    undocumented = []
    for key, doc in _leaves(PipelineConfig):
        n = where[key]  # every field is written
        above = []
        for line in reversed(lines[: n - 1]):
            if not line.strip().startswith("#"):
                break
            above.insert(0, line.strip()[2:])
        if doc is None:
            undocumented.append(key)
        else:
            assert " ".join(doc.split()) in " ".join(above), (key, above)
    assert undocumented == []


def _edited(tmp_path: Path, old: str, new: str) -> tuple[Path, int]:
    """The sample's settings saved, with the line ``old`` replaced by ``new`` (one occurrence); its line number."""
    path = PipelineConfig.load(SAMPLE_YAML).save(tmp_path / "ws" / "m2m.yaml")
    lines = path.read_text().splitlines()
    n = [i for i, line in enumerate(lines) if line == old]
    assert len(n) == 1, old
    lines[n[0]] = new
    path.write_text("\n".join(lines) + "\n")
    return path, n[0] + 1


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        ("  minutes: 6.0", "  minuets: 6.0", r"scene: unknown setting\(s\) minuets; did you mean minutes\?.*; fix"),
        ("scene:", "sceen:", r"unknown setting\(s\) sceen; did you mean scene\?"),
        ("  max_keyframes: 40", "  max_keyframes: forty", r"capture\.max_keyframes: expected an integer, got 'forty'"),
        ("    - croissant", "    - {name: croissant}", r"objects\.names\[1\]: expected text"),
        ("  matching: auto", "  matching: sometimes", r"sfm\.matching: 'sometimes' is not one of auto"),
        ("  snap_to_table: true", "  snap_to_table: 'no'", r"world\.snap_to_table: expected true or false"),
        ("    iterations: 1000", "    iterations: []", r"objects\.matting\.iterations: expected an integer"),
    ],
    ids=["unknown key", "unknown section", "wrong type", "list item", "choice", "yes/no text", "nested section"],
)
def test_a_bad_value_is_named_with_its_line(tmp_path, capsys, old, new, message):
    path, n = _edited(tmp_path, old, new)
    with pytest.raises(ConfigError, match=f"^{re.escape(str(path))}, line {n}: {message}"):
        PipelineConfig.load(path)
    before = sorted(p.name for p in path.parent.iterdir())
    assert main(["run", "-w", str(path.parent)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"m2m: error: {path}, line {n}: ") and "Traceback" not in err
    assert sorted(p.name for p in path.parent.iterdir()) == before == ["m2m.yaml"]  # nothing written


def test_a_key_given_twice_is_named_with_both_lines(tmp_path):
    path = PipelineConfig.load(SAMPLE_YAML).save(tmp_path / "m2m.yaml")
    first = yaml_lines(path)[("scene",)]
    path.write_text(path.read_text() + "scene:\n  minutes: 1.0\n")
    last = len(path.read_text().splitlines()) - 1
    with pytest.raises(InputError, match=f"line {last}: scene is given twice \\(also on line {first}\\)"):
        PipelineConfig.load(path)


def test_missing_files_are_named_with_their_lines_before_anything_runs(tmp_path, capsys):
    ws = Workspace(tmp_path / "ws")
    cfg = PipelineConfig.load(SAMPLE_YAML)
    cfg = replace(cfg, head_view=replace(cfg.head_view, photo=tmp_path / "no_photo.png"),
                  objects=replace(cfg.objects, mesh={"banana": tmp_path / "no_mesh.obj"}))  # fmt: skip
    cfg.save(ws.config_file)
    lines = yaml_lines(ws.config_file)
    assert main(["run", "-w", str(ws.root)]) == 2
    err = capsys.readouterr().err
    assert f"{ws.config_file}: 2 files not found:" in err
    assert f"line {lines[('head_view', 'photo')]}: head_view.photo: {tmp_path / 'no_photo.png'}" in err
    assert f"line {lines[('objects', 'mesh', 'banana')]}: objects.mesh.banana: {tmp_path / 'no_mesh.obj'}" in err
    assert sorted(p.name for p in ws.root.iterdir()) == ["m2m.yaml"]
    # one missing file: its line first; and only the stages run are checked
    cfg = replace(cfg, objects=PipelineConfig.load(SAMPLE_YAML).objects)
    cfg.save(ws.config_file)
    cfg, where = PipelineConfig.read(ws.config_file)
    with pytest.raises(ConfigError, match=f"line {lines[('head_view', 'photo')]}: head_view.photo: .* not found; fix"):
        plan_run(ws, cfg, where)
    assert plan_run(ws, cfg, where, until="scene") == dict.fromkeys(["capture", "sfm", "align", "handeye", "scene"])


def _plain(tmp_path: Path, **sections) -> PipelineConfig:
    """A capture and a board, nothing optional; ``sections``: {section: {field: value}} on top."""
    cfg = PipelineConfig()
    cfg = replace(cfg, capture=replace(cfg.capture, source=SAMPLE / "scene.mp4"), board=SAMPLE / "board.json")
    for name, changes in sections.items():
        cfg = replace(cfg, **{name: replace(getattr(cfg, name), **changes) if isinstance(changes, dict) else changes})
    return cfg


def test_stages_whose_optional_inputs_are_absent_are_skipped_with_the_reason(tmp_path):
    ws = Workspace(tmp_path / "ws")
    plan = plan_run(ws, _plain(tmp_path))
    assert [n for n, why in plan.items() if why is None] == ["capture", "sfm", "align", "scene", "objects"]
    assert plan["handeye"].startswith("no hand-eye images (handeye.images and handeye.joints are not set)")
    assert plan["head_view"].startswith("no head-camera calibration")
    assert "the world's head camera needs one: give handeye.images" in plan["world"]
    assert plan["generate"] == "no world (skipped above)"
    # a keyframe a fixed camera took is the world's head camera: the pipeline's setting, which capture keeps
    images = tmp_path / "images"
    images.mkdir()
    for name in ("0001.jpg", "right.jpg"):
        shutil.copy(SAMPLE / "head_view.png", images / name)
    fixed = _plain(tmp_path, head_keyframe="right.jpg", capture={"source": images})
    assert fixed.world.head_keyframe == fixed.capture.head_keyframe == "right.jpg"
    plan = plan_run(ws, fixed)
    assert plan["world"] is None and plan["head_view"].startswith("no head-camera calibration")
    # checked at the door: an image the folder lacks, or a video (its frames are the moving camera's)
    with pytest.raises(ConfigError, match="head_keyframe 'left.jpg': no such image in .*images; put the fixed"):
        plan_run(ws, replace(fixed, head_keyframe="left.jpg"))
    with pytest.raises(ConfigError, match="head_keyframe 'right.jpg': the capture is a video .*scene.mp4"):
        plan_run(ws, _plain(tmp_path, head_keyframe="right.jpg"))
    # the capture stage run on its own (`m2m capture`) refuses it too, and writes nothing
    from mirage2matter.capture import CaptureError
    from mirage2matter.stages import get_stage, run_stage

    video = _plain(tmp_path, head_keyframe="right.jpg").capture
    with pytest.raises(CaptureError, match="scene.mp4: a video; right.jpg must name images of an image folder"):
        run_stage(get_stage("capture"), ws, video, log=lambda s: None)
    assert not ws.capture_dir.exists()
    # a head camera calibrated earlier (by hand): kept, and the stages after it run; no tasks -> no demonstrations
    ws.handeye_file.parent.mkdir(parents=True)
    ws.handeye_file.write_text("{}")
    plan = plan_run(ws, _plain(tmp_path))
    assert plan["handeye"].endswith("calib/handeye.json of an earlier calibration is kept")
    assert plan["world"] is None and plan["generate"].startswith("no tasks")
    assert plan["head_view"].startswith("no head-camera photo to compare the scene with (head_view.photo is not set)")
    photo = {"photo": SAMPLE / "head_view.png"}
    plan = plan_run(ws, _plain(tmp_path, generate={"task": ("grasp banana",)}, head_view=photo))
    assert plan["generate"] is None and plan["head_view"] is None
    # the hand-eye calibration given: it runs, and a wrist camera's is no head camera
    he = {"images": SAMPLE / "handeye/images", "joints": SAMPLE / "handeye/joints.json",
          "board": SAMPLE / "handeye/board.json", "intrinsics": SAMPLE / "ground_truth.json"}  # fmt: skip
    plan = plan_run(ws, _plain(tmp_path, handeye=he, head_view=photo, generate={"task": ("x",)}))
    assert set(plan.values()) == {None}
    plan = plan_run(ws, _plain(tmp_path, handeye={**he, "mount": "wrist"}))
    assert plan["head_view"].startswith("the hand-eye calibration is of a wrist camera") and plan["world"]
    # imported poses need no capture
    transforms = tmp_path / "transforms.json"
    transforms.write_text("{}")
    plan = plan_run(ws, _plain(tmp_path, capture={"source": None}, sfm={"from_transforms": transforms}))
    assert plan["capture"] == "sfm.from_transforms imports posed images" and plan["sfm"] is None


@pytest.mark.parametrize(
    ("sections", "field", "message"),
    [
        ({"capture": {"source": None}}, "capture.source", r"capture\.source: no video or image folder; give"),
        ({"board": None}, "board", r"board: no calibration target; .*align\.unaligned: true"),
        (
            {"handeye": {"images": SAMPLE / "handeye/images"}},
            "handeye",
            r"the hand-eye calibration lacks handeye\.joints .*handeye\.board .*handeye\.intrinsics \(the head "
            r"camera's",
        ),
        ({"robot": "robbie"}, "robot", r"robot: unknown robot 'robbie'; known robots: panda"),
        ({"scene": {"minutes": 0.0}}, "scene", r"section scene: train-scene: give a positive --minutes budget"),
        (
            {"head_photo_joints": [0.1, 0.2]},
            "head_photo_joints",
            r"head_photo_joints: 2 values given; panda has 7 arm joints",
        ),
    ],
    ids=[
        "no capture",
        "no board",
        "hand-eye half given",
        "unknown robot",
        "a stage refuses a value",
        "a head photo's joint state that is not the robot's",
    ],
)
def test_what_a_run_cannot_do_without_is_named_with_its_line(tmp_path, sections, field, message):
    ws = Workspace(tmp_path / "ws")
    _plain(tmp_path, **sections).save(ws.config_file)
    cfg, where = PipelineConfig.read(ws.config_file)
    assert where.line(field) is not None
    with pytest.raises(ConfigError, match=f"^{re.escape(str(ws.config_file))}, line {where.line(field)}: {message}"):
        plan_run(ws, cfg, where)
    assert not (ws.root / "pipeline.json").exists()
    if "align" in sections:  # a scene-only workspace says so instead
        assert plan_run(ws, replace(cfg, align=replace(cfg.align, unaligned=True)), where)["align"] is None


def test_settings_file_points_at_the_nearest_line_it_has():
    where = SettingsFile(Path("m2m.yaml"), {("objects",): 3, ("objects", "names"): 5, ("objects", "names", 1): 7})
    assert where.line("objects.names[1]") == 7 and where.line("objects.names[4]") == 5
    assert where.line("objects.mesh.my.mesh") == 3 and where.line("scene.minutes") is None
    assert where.at("scene.minutes") == "m2m.yaml" and where.at("objects.names") == "m2m.yaml, line 5"


def test_a_failing_stage_is_named_with_how_to_go_on(tmp_path):
    images = tmp_path / "three"
    images.mkdir()
    from PIL import Image

    for i in range(3):
        Image.new("RGB", (64, 48), (40 * i, 90, 160)).save(images / f"{i}.png")
    ws = Workspace(tmp_path / "ws")
    cfg = _plain(tmp_path, capture={"source": images})
    with pytest.raises(PipelineError) as e:
        run_pipeline(ws, cfg, log=lambda s: None, until="capture")
    assert str(e.value).startswith("capture (stage 1 of 1, `m2m capture`): ")
    assert "only 3 frame(s), fewer than min_keyframes=8" in str(e.value)
    assert f"run `m2m run -w {ws.root}` again: the finished stages are kept" in str(e.value)
    assert not ws.record_file.exists() or "capture" not in json.loads(ws.record_file.read_text())
    with pytest.raises(ConfigError, match="--from align comes after --until capture"):
        run_pipeline(ws, cfg, until="capture", start="align")


def test_an_m2m_yaml_with_the_robot_under_the_sections_still_loads(tmp_path):
    """Before the robot was the pipeline's, `m2m init --robot` wrote it under align, world and (as its model file)
    handeye: those name one robot, which becomes the top-level one; sections naming different robots are an error
    saying how to fix the file."""
    from mirage2matter.robots import get_robot

    path = tmp_path / "m2m.yaml"
    model = get_robot("ur5e").model
    path.write_text(f"align: {{robot: ur5e}}\nhandeye: {{robot: {model}}}\nworld: {{robot: ur5e, max_mm: 2.0}}\n")
    cfg = PipelineConfig.load(path)
    assert cfg.robot == cfg.align.robot == cfg.handeye.robot == cfg.world.robot == "ur5e" and cfg.world.max_mm == 2.0
    cfg.save(path)  # written the new way: once, at the top
    assert "\nrobot: ur5e\n" in path.read_text() and PipelineConfig.load(path) == cfg
    path.write_text("align: {robot: ur5e}\nworld: {robot: panda}\n")
    with pytest.raises(ConfigError, match=r"align\.robot: ur5e, world\.robot: panda: one robot for the whole pipeline "
                       r"now, set once at the top of the file; write `robot: \.\.\.` there"):  # fmt: skip
        PipelineConfig.load(path)


def test_an_m2m_yaml_with_head_view_photo_joints_still_loads(tmp_path):
    """Before the head photo's joint state was the pipeline's (train-scene's head photo reads it too), it was
    head_view.photo_joints: it moves to the top as head_photo_joints, every stage that reads it holding it (a null,
    as every old file wrote, is the default); the top and head_view naming two states is an error saying how to fix
    the file; a bad value is named at its old line."""
    path = tmp_path / "m2m.yaml"
    q = [0.1, -0.7, 0.0, -2.3, 0.0, 1.5, 0.7]
    path.write_text(f"head_view:\n  photo: null\n  photo_joints: {q}\n  backend: cpu\n")
    cfg = PipelineConfig.load(path)
    assert cfg.head_photo_joints == cfg.head_view.head_photo_joints == cfg.scene.head_photo_joints == q
    assert cfg.head_view.backend == "cpu"
    cfg.save(path)  # written the new way: once, at the top
    text = path.read_text()
    assert f"\nhead_photo_joints: {q}\n" in text and "photo_joints" not in text.replace("head_photo_joints", "")
    assert PipelineConfig.load(path) == cfg
    path.write_text("head_view: {photo_joints: null}\n")
    assert PipelineConfig.load(path) == PipelineConfig()
    path.write_text(f"head_photo_joints: {q}\nhead_view: {{photo_joints: {q}}}\n")  # the same state twice: one
    assert PipelineConfig.load(path).head_photo_joints == q
    path.write_text(f"head_photo_joints: {q}\nhead_view: {{photo_joints: [0.0, 0, 0, 0, 0, 0, 0]}}\n")
    with pytest.raises(
        ConfigError,
        match=r"head_view\.photo_joints: \[0\.0, 0, .*\], head_photo_joints: \[0\.1, .*\]: "
        r"one head_photo_joints for the whole pipeline now, .*; remove photo_joints from head_view",
    ):
        PipelineConfig.load(path)
    path.write_text("robot: panda\nhead_view:\n  photo_joints: [0.1, fast]\n")
    with pytest.raises(ConfigError, match=r"m2m\.yaml, line 3: head_photo_joints"):
        PipelineConfig.load(path)
    # a section naming the pipeline's setting: one state, moved to the top; two: an error
    path.write_text(f"scene: {{head_photo_joints: {q}}}\n")
    assert PipelineConfig.load(path).head_view.head_photo_joints == q
    path.write_text(f"scene: {{head_photo_joints: {q}}}\nhead_view: {{head_photo_joints: [0.0, 0, 0, 0, 0, 0, 0]}}\n")
    with pytest.raises(ConfigError, match=r"one head_photo_joints for the whole pipeline now"):
        PipelineConfig.load(path)

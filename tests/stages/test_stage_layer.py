"""One stage layer: every stage's defaults live in its Config, and `m2m <stage>`, `m2m demo` and the Config agree;
the skip/resume rule is one fingerprint of config and input content."""

import argparse
import dataclasses
import json
import re

import pytest

from fixtures import SAMPLE
from mirage2matter.cli import build_parser, main
from mirage2matter.configs import field_docs, from_dict, from_flags, to_dict
from mirage2matter.stages import STAGES, get_stage, run_stage
from mirage2matter.stages.base import PipelineSettings
from mirage2matter.stages.pipeline import PipelineConfig
from mirage2matter.workspace import Workspace, WorkspaceError

SAMPLE_YAML = SAMPLE / "m2m.yaml"


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return action.choices


def _config_actions(p: argparse.ArgumentParser, own=("help", "workspace", "force")) -> list[argparse.Action]:
    """The actions generated from Config fields (the command's own arguments left out)."""
    return [a for a in p._actions if a.dest not in own]


def _all_fields(cls, prefix=""):
    """(dotted name, field) of every leaf field, nested Configs walked."""
    for f in dataclasses.fields(cls):
        value = getattr(cls(), f.name)
        if dataclasses.is_dataclass(value):
            yield from _all_fields(type(value), f"{prefix}{f.name}.")
        else:
            yield prefix + f.name, f


def test_pipeline_config_has_the_pipelines_settings_then_one_section_per_stage_in_order():
    own = [f.name for f in dataclasses.fields(PipelineSettings)]
    assert [f.name for f in dataclasses.fields(PipelineConfig)] == [*own, *(s.name for s in STAGES)]
    # the robot is the pipeline's: every stage that takes one reads that one
    cfg = dataclasses.replace(PipelineConfig(), robot="ur5e")
    assert cfg.align.robot == cfg.handeye.robot == cfg.world.robot == "ur5e"
    assert cfg.with_stage("world", dataclasses.replace(cfg.world, robot="panda")).align.robot == "panda"
    assert [get_stage(s.command) for s in STAGES] == list(STAGES)


@pytest.mark.parametrize("stage", STAGES, ids=[s.name for s in STAGES])
def test_stage_command_defaults_are_the_configs(stage):
    """Walk the stage command's actions: every config flag comes from a Config field, holds no default of its
    own (argparse.SUPPRESS: absent unless given), and parsing no flag gives exactly the Config's defaults."""
    p = _subparsers(build_parser())[stage.command]
    actions = _config_actions(p)
    fields = {name for name, f in _all_fields(stage.config) if f.metadata.get("flag", True)}
    assert {a.dest for a in actions} == fields
    for a in actions:
        if a.option_strings:
            assert a.default is argparse.SUPPRESS, f"--{a.dest} carries its own default {a.default!r}"
        else:  # the positional: absent is None, which from_flags skips
            assert a.default is None
    ns = p.parse_args(["-w", "ws"])
    assert from_flags(stage.config, ns) == stage.config()
    # every field is documented (the flag's help)
    docs = field_docs(stage.config)
    undocumented = [f.name for f in dataclasses.fields(stage.config) if f.name not in docs]
    assert not undocumented, f"{stage.name}: fields without a doc line: {undocumented}"
    for a in actions:  # the default said once: "(default: X)", or in the doc's own words ("Off by default")
        assert a.help and not a.help.startswith("(default:"), a.dest
        assert "(default:" in a.help or re.search(r"\bdefault\b", a.help, re.IGNORECASE), a.dest
        assert a.help.count("(default:") <= 1, a.dest


def test_nested_configs_are_documented_too():
    for stage in STAGES:
        for f in dataclasses.fields(stage.config):
            value = getattr(stage.config(), f.name)
            if dataclasses.is_dataclass(value):
                missing = {g.name for g in dataclasses.fields(value)} - set(field_docs(type(value)))
                assert not missing, f"{stage.name}.{f.name}: undocumented {sorted(missing)}"


def test_demo_uses_the_configs_defaults_except_what_the_samples_yaml_names():
    """The demo's settings are each Config's defaults changed only by the keys samples/tabletop/m2m.yaml writes
    (its inputs and budget), and `m2m demo` without flags parses to exactly those."""
    import yaml

    written = yaml.safe_load(SAMPLE_YAML.read_text())
    demo_cfg = PipelineConfig.load(SAMPLE_YAML)
    defaults = PipelineConfig()
    pipeline = {k for k in written if k not in {s.name for s in STAGES}}  # the pipeline's, every stage that reads it
    for stage in STAGES:
        mine, default = to_dict(getattr(demo_cfg, stage.name)), to_dict(getattr(defaults, stage.name))
        changed = {k for k in mine if mine[k] != default[k]}
        assert changed <= set(written.get(stage.name) or {}) | pipeline, (stage.name, changed)
    demo = _subparsers(build_parser())["demo"]
    ns = demo.parse_args([])
    assert from_flags(PipelineConfig, ns, demo_cfg) == demo_cfg
    for a in _config_actions(demo, own=("help", "workspace", "sample", "until", "start")):
        assert a.default is argparse.SUPPRESS, a.dest
    # and a flag changes just its field
    ns = demo.parse_args(["--scene.minutes", "2", "--objects.splat.iterations", "10"])
    got = from_flags(PipelineConfig, ns, demo_cfg)
    assert got.scene.minutes == 2 and got.objects.splat.iterations == 10
    assert dataclasses.replace(got, scene=demo_cfg.scene, objects=demo_cfg.objects) == demo_cfg


def test_m2m_yaml_round_trips_and_names_bad_fields(tmp_path):
    cfg = PipelineConfig.load(SAMPLE_YAML)
    path = cfg.save(tmp_path / "m2m.yaml")
    assert PipelineConfig.load(path) == cfg
    path.write_text("scene:\n  minuets: 3\n")
    with pytest.raises(Exception, match=r"m2m.yaml, line 2: scene: unknown setting\(s\) minuets; did you mean minutes"):
        PipelineConfig.load(path)
    path.write_text("world:\n  snap_to_table: 'no'\n")
    with pytest.raises(Exception, match="line 2: world.snap_to_table: expected true or false"):
        PipelineConfig.load(path)
    with pytest.raises(Exception, match="unknown setting"):
        from_dict(PipelineConfig, {"sceen": {}})


def test_a_stage_is_skipped_only_while_its_config_and_input_content_are_the_same(tmp_path):
    """The one skip/resume rule, on the capture stage over a small image folder."""
    import numpy as np
    from PIL import Image

    rng = np.random.default_rng(0)
    src = tmp_path / "images"
    src.mkdir()
    base = rng.integers(0, 255, (60, 80, 3), dtype=np.uint8)
    for i in range(10):  # a textured image drifting sideways: parallax between frames
        Image.fromarray(np.roll(base, 3 * i, axis=1)).save(src / f"{i:02d}.png")
    ws = Workspace(tmp_path / "ws")
    stage = get_stage("capture")
    cfg = stage.config(source=src, max_keyframes=8, min_parallax_px=0.0)
    logs = []
    first, skipped = run_stage(stage, ws, cfg, logs.append)
    assert not skipped and first["keyframes"] == 8 and ws.keyframes_file.is_file()
    record = json.loads(ws.record_file.read_text())["capture"]
    assert record["summary"] == first and record["config"]["max_keyframes"] == 8
    assert run_stage(stage, ws, cfg, logs.append) == (first, True)
    # changed input content -> runs again; changed config -> runs again; --force -> runs again
    Image.fromarray(np.roll(base, 1, axis=0)).save(src / "00.png")
    assert run_stage(stage, ws, cfg, logs.append)[1] is False
    assert run_stage(stage, ws, cfg, logs.append)[1] is True
    assert run_stage(stage, ws, dataclasses.replace(cfg, max_keyframes=9), logs.append)[1] is False
    assert run_stage(stage, ws, dataclasses.replace(cfg, max_keyframes=9), logs.append, force=True)[1] is False
    # a missing output makes it run again too
    ws.keyframes_file.unlink()
    assert run_stage(stage, ws, dataclasses.replace(cfg, max_keyframes=9), logs.append)[1] is False


def test_a_missing_input_names_the_command_that_writes_it(tmp_path, capsys):
    ws = Workspace(tmp_path / "ws")
    for command, earlier in (("sfm", "capture"), ("train-scene", "sfm"), ("objects", "align-scene"),
                             ("compose", "calibrate-handeye"), ("generate", "compose")):  # fmt: skip
        stage = get_stage(command)
        cfg = stage.config(task=("grasp banana",)) if command == "generate" else stage.config()
        with pytest.raises(WorkspaceError, match=f"run `m2m {earlier} -w"):
            run_stage(stage, ws, cfg)
    assert not ws.root.exists()  # nothing was written
    assert main(["train-scene", "-w", str(ws.root)]) == 2
    assert "run `m2m sfm -w" in capsys.readouterr().err
    assert main(["generate", "-w", str(ws.root)]) == 2
    assert "no task" in capsys.readouterr().err
    assert main(["train-scene", "-w", str(ws.root), "--minuets", "3"]) == 2
    assert "unrecognized arguments: --minuets" in capsys.readouterr().err


def test_stage_commands_save_the_settings_they_ran_with(tmp_path, capsys):
    """A stage command starts from the workspace's m2m.yaml and writes back what it ran with, so a user running
    stages by hand and `m2m demo` / `m2m run` use one configuration."""
    import numpy as np
    from PIL import Image

    src = tmp_path / "images"
    src.mkdir()
    base = np.random.default_rng(1).integers(0, 255, (60, 80, 3), dtype=np.uint8)
    for i in range(10):
        Image.fromarray(np.roll(base, 3 * i, axis=1)).save(src / f"{i:02d}.png")
    ws = tmp_path / "ws"
    assert main(["capture", str(src), "-w", str(ws), "--max-keyframes", "9", "--min-parallax-px", "0"]) == 0
    saved = PipelineConfig.load(ws / "m2m.yaml")
    assert saved.capture.max_keyframes == 9 and saved.capture.source == src.resolve()
    assert saved.scene == PipelineConfig().scene
    capsys.readouterr()
    assert main(["capture", "-w", str(ws)]) == 0  # the saved source and settings: up to date
    assert "up to date" in capsys.readouterr().out

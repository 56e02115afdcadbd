"""``m2m init``: the workspace's m2m.yaml from a user's inputs; read back, the same settings as the sample's own
m2m.yaml names; every input checked before anything is written."""

from __future__ import annotations

import json
import shutil

import pytest

from fixtures import SAMPLE
from mirage2matter.cli import main
from mirage2matter.stages.pipeline import PipelineConfig

S = str(SAMPLE)
SAMPLE_FLAGS = [
    "--video", f"{S}/scene.mp4", "--intrinsics", f"{S}/ground_truth.json", "--board", f"{S}/board.json",
    "--board-pose", f"{S}/ground_truth.json", "--handeye-images", f"{S}/handeye/images",
    "--handeye-poses", f"{S}/handeye/joints.json", "--handeye-board", f"{S}/handeye/board.json",
    "--handeye-intrinsics", f"{S}/ground_truth.json", "--head-photo", f"{S}/head_view.png",
    "--objects", "banana", "croissant", "button", "--task", "grasp banana", "grasp croissant", "press button",
    "--task", "push croissant --direction 0,1 --distance 0.1", "--episodes", "3",
    "--capture.max-keyframes", "40", "--scene.minutes", "6", "--generate.workers", "2",
    "--capture-joints", "-0.35", "-0.785", "0", "-2.356", "0", "1.571", "0.785",
    "--capture-move", "360", "0.7266", "0.7754", "0", "-1.5499", "0", "1.5268", "0.785",  # the sample's move half-way
]  # fmt: skip


def test_init_with_the_samples_inputs_writes_the_samples_settings(tmp_path, capsys):
    """The sample's own m2m.yaml (hand-written) and `m2m init` with the same inputs give the same settings."""
    ws = tmp_path / "ws"
    assert main(["init", "-w", str(ws), *SAMPLE_FLAGS]) == 0
    out = capsys.readouterr().out
    assert "m2m run will run  capture, sfm, align, handeye, scene, head_view, objects, world, generate" in out
    assert PipelineConfig.load(ws / "m2m.yaml") == PipelineConfig.load(SAMPLE / "m2m.yaml")
    text = (ws / "m2m.yaml").read_text()
    assert "# ---- handeye (`m2m calibrate-handeye`)\n" in text
    assert "  # successful episodes wanted per task\n  episodes: 3\n" in text
    assert f"  source: {(SAMPLE / 'scene.mp4').resolve()}\n" in text  # outside the workspace: absolute
    # an existing m2m.yaml is not replaced without --force
    assert main(["init", "-w", str(ws), "--video", f"{S}/scene.mp4", "--board", f"{S}/board.json"]) == 2
    assert "m2m.yaml exists; edit it, or `m2m init --force" in capsys.readouterr().err
    assert (ws / "m2m.yaml").read_text() == text
    assert main(["init", "-w", str(ws), "--force", "--video", f"{S}/scene.mp4", "--board", f"{S}/board.json"]) == 0
    assert PipelineConfig.load(ws / "m2m.yaml").generate.task == ()


def test_inputs_inside_the_workspace_are_written_relative_to_it(tmp_path, capsys):
    ws = tmp_path / "ws"
    (ws / "inputs").mkdir(parents=True)
    shutil.copy(SAMPLE / "board.json", ws / "inputs" / "board.json")
    assert main(["init", "-w", str(ws), "--video", f"{S}/scene.mp4", "--board", str(ws / "inputs" / "board.json"),
                 "--robot", "panda"]) == 0  # fmt: skip
    out = capsys.readouterr().out
    text = (ws / "m2m.yaml").read_text()
    assert "\nboard: inputs/board.json\n" in text  # the pipeline's: at the top
    moved = tmp_path / "moved"
    (ws / "capture").mkdir()
    shutil.move(ws, moved)  # a workspace moved with its inputs still reads them
    cfg = PipelineConfig.load(moved / "m2m.yaml")
    assert cfg.board == cfg.align.board == moved / "inputs" / "board.json"
    assert cfg.world.robot == cfg.align.robot == "panda"
    # no hand-eye images, no tasks: the run skips what needs them, and says so now
    for line in ("and skip handeye   no hand-eye images", "and skip head_view no head-camera calibration",
                 "and skip world     no head-camera calibration", "and skip generate  no world"):  # fmt: skip
        assert line in out, out


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--video", f"{S}/nothing.mp4", "--board", f"{S}/board.json", "--head-photo", "no.png",
          "--objects.masks", "no_masks"],
         r"3 problems, nothing written:\n  - --video .*nothing.mp4: not found\n  - --head-photo no.png: not found\n"
         r"  - --objects.masks no_masks: not found"),
        (["--video", S, "--board", f"{S}/board.json"], "--video .* is a folder; give the video file"),
        (["--board", f"{S}/board.json"], "no capture: give --video FILE or --images DIR"),
        (["--video", f"{S}/scene.mp4"], "no calibration target: give --board FILE"),
        (["--video", f"{S}/scene.mp4", "--board", f"{S}/ground_truth.json"],
         "--board: .*ground_truth.json: BoardSpec JSON has unknown keys"),
        (["--video", f"{S}/scene.mp4", "--board", f"{S}/board.json", "--handeye-images", f"{S}/handeye/images"],
         "the hand-eye calibration also needs --handeye-poses / --handeye.joints, --handeye-intrinsics"),
        (["--video", f"{S}/scene.mp4", "--board", f"{S}/board.json", "--intrinsics", f"{S}/board.json"],
         "--intrinsics / --sfm.intrinsics: .*board.json"),
        (["--video", f"{S}/scene.mp4", "--board", f"{S}/board.json", "--robot", "robbie"],
         "--robot: unknown robot 'robbie'; known robots: panda"),
        (["--video", f"{S}/scene.mp4", "--board", f"{S}/board.json", "--scene.minutes", "0"],
         r"section scene: train-scene: give a positive --minutes budget .*\(flag --scene\.\*\)"),
        ([*SAMPLE_FLAGS[:20], "--handeye.link", "hnd"],
         r"--handeye.link: .*joints.json: the views give joint angles, so forward kinematics must reach the link: "
         r"link 'hnd' not in panda.xml; links: .*hand.*; frames the robot's spec names: EE"),
    ],
    ids=["missing files", "video is a folder", "no capture", "no board", "not a board", "hand-eye half given",
         "not intrinsics", "unknown robot", "a stage refuses a value", "hand-eye link unknown"],  # fmt: skip
)
def test_bad_inputs_are_named_by_their_flag_and_nothing_is_written(tmp_path, capsys, flags, message):
    import re

    ws = tmp_path / "ws"
    assert main(["init", "-w", str(ws), *flags]) == 2
    err = capsys.readouterr().err
    assert err.startswith("m2m: error: ") and re.search(message, err), err
    assert not ws.exists()


def test_init_refuses_a_poses_base_frame_the_robot_lacks(tmp_path, capsys):
    """End-effector poses in a base frame (base_frame) the robot neither has nor names: refused at the door, naming
    the file and the frame."""
    views = json.loads((SAMPLE / "handeye" / "joints.json").read_text())["views"]
    poses = tmp_path / "poses.json"
    poses.write_text(json.dumps({"link": "hand", "base_frame": "PolyScope",
                                 "views": [{"image": v["image"], "T_base_hand": v["T_base_hand"]} for v in views]}))
    flags = [str(poses) if f.endswith("joints.json") else f for f in SAMPLE_FLAGS]
    assert main(["init", "-w", str(tmp_path / "ws"), *flags]) == 2
    err = capsys.readouterr().err
    assert "poses.json: base_frame: link 'PolyScope' not in panda.xml" in err, err
    assert not (tmp_path / "ws").exists()


def test_init_takes_the_robots_joint_state_while_filming(tmp_path, capsys):
    """--capture-joints lands in the pipeline's capture_joints and the summary says it; without it, the home pose is
    said."""
    from fixtures import SAMPLE
    from mirage2matter.cli import main
    from mirage2matter.stages.pipeline import PipelineConfig

    q = ["0.1", "-0.785", "0", "-2.356", "0", "1.571", "0.785"]
    ws = tmp_path / "ws"
    args = ["init", "-w", str(ws), "--video", str(SAMPLE / "scene.mp4"), "--board", str(SAMPLE / "board.json")]
    assert main([*args, "--capture-joints", *q]) == 0
    assert PipelineConfig.load(ws / "m2m.yaml").capture_joints == [float(v) for v in q]
    assert "while filming: [0.1," in capsys.readouterr().out
    assert main([*args, "--force"]) == 0
    assert "its home pose (give --capture-joints" in capsys.readouterr().out
    assert main([*args, "--force", "--capture-joints", "0", "1"]) == 2
    assert "2 values given" in capsys.readouterr().err
    # a move while filming: from frame 360 on, the base turned by 1.2 rad
    moved = ["1.2", *q[1:]]
    assert main([*args, "--force", "--capture-joints", *q, "--capture-move", "360", *moved]) == 0
    cfg = PipelineConfig.load(ws / "m2m.yaml")
    assert cfg.capture_moves == cfg.align.capture_moves == cfg.sfm.capture_moves == {360: [float(v) for v in moved]}
    assert "moved at frame 360 to [1.2," in capsys.readouterr().out
    for bad, words in ((["360.5", *moved], "the video frame (a whole number)"), (["0", *moved], "frame 0"),
                       (["360", "0", "1"], "capture_moves[360]: 2 values given")):  # fmt: skip
        assert main([*args, "--force", "--capture-move", *bad]) == 2
        assert words in capsys.readouterr().err


def test_init_lists_five_independent_mistakes_together_and_writes_nothing(tmp_path, capsys):
    """Issue 65: an unparseable task, an object named like a path, NaN joints in the hand-eye poses, a robot spec with
    its tool centre in millimetres and a capture image over 16384 px: all five in one message, exit 2, nothing
    written."""
    import json
    from pathlib import Path

    from PIL import Image

    from mirage2matter.robots import get_robot

    images = tmp_path / "images"
    images.mkdir()
    Image.new("L", (17000, 100)).save(images / "0.png")
    poses = json.loads((SAMPLE / "handeye" / "joints.json").read_text())
    poses["views"][2]["joints"][1] = float("nan")
    (tmp_path / "joints.json").write_text(json.dumps(poses))
    spec = (Path(get_robot("panda").source)).read_text().replace("tcp: [0.0, 0.0, 0.1034]", "tcp: [0.0, 0.0, 103.4]")
    (tmp_path / "robot.yaml").write_text(spec)  # the tool centre in millimetres
    ws = tmp_path / "ws"
    argv = ["init", "-w", str(ws), "--images", str(images), "--board", f"{S}/board.json", "--handeye-images",
            f"{S}/handeye/images", "--handeye-poses", str(tmp_path / "joints.json"), "--handeye-intrinsics",
            f"{S}/ground_truth.json", "--objects", "banana", "../evil", "--task", "grasp banana", "fly to the moon",
            "--robot", str(tmp_path / "robot.yaml")]  # fmt: skip
    capsys.readouterr()
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("m2m: error: ") and "problems, nothing written" in err and "Traceback" not in err, err
    for words in ("unknown task 'fly'", "'../evil'", "views[2]", "end_effector.tcp", "0.png is 17000x100"):
        assert words in err, f"{words!r} not in {err}"
    assert not ws.exists()

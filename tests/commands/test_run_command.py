"""``m2m run``: the stages of a workspace's m2m.yaml (from ``m2m init``) with no ground truth; part of them with
``--until`` / ``--from``, optional stages skipped with the reason, and a run killed inside a stage resumed at that
stage on the next run (the finished ones kept)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from fixtures import SAMPLE
from fixtures.browser import chromium, open_page
from mirage2matter.cli import main
from mirage2matter.export import validate
from mirage2matter.stages.pipeline import PipelineConfig
from mirage2matter.workspace import Workspace

S = str(SAMPLE)


def _recorded(ws: Workspace) -> list[str]:
    try:
        return list(json.loads(ws.record_file.read_text()))
    except (OSError, ValueError):
        return []


def _kill_once_recorded(args: list[str], ws: Workspace, finished: str, log: Path, after: float = 0.5,
                        ready=lambda: True, timeout: float = 600) -> int:  # fmt: skip
    """Start ``m2m *args``; SIGKILL it (and its workers) ``after`` s once ``finished`` is in pipeline.json and
    ``ready()`` holds; its exit status."""
    with open(log, "w") as err:
        p = subprocess.Popen([sys.executable, "-m", "mirage2matter", *args], stdout=subprocess.DEVNULL, stderr=err,
                             start_new_session=True)  # fmt: skip
        t0 = time.monotonic()
        while p.poll() is None and time.monotonic() - t0 < timeout:
            if finished in _recorded(ws) and ready():
                time.sleep(after)
                break
            time.sleep(0.1)
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
        return p.wait()


def test_run_is_killed_in_a_stage_and_resumes_there(tmp_path, capsys, sample_dir):
    ws = Workspace(tmp_path / "ws")
    assert main(["init", "-w", str(ws.root), "--video", f"{S}/scene.mp4", "--board", f"{S}/board.json",
                 "--intrinsics", f"{S}/ground_truth.json", "--capture.max-keyframes", "12"]) == 0  # fmt: skip
    capsys.readouterr()
    rc = _kill_once_recorded(["run", "-w", str(ws.root), "--until", "sfm"], ws, "capture", tmp_path / "killed.log")
    assert rc == -signal.SIGKILL and _recorded(ws) == ["capture"]
    assert "[2/2] sfm ...\n" in (tmp_path / "killed.log").read_text()  # killed inside sfm

    assert main(["run", "-w", str(ws.root), "--until", "sfm"]) == 0
    out, err = capsys.readouterr()
    assert "[1/2] capture: done earlier - 12 keyframes" in err
    assert "sfm: resuming the interrupted run" in err and "[2/2] sfm: registered 12/12 keyframes" in err
    assert "m2m run finished" in out and "run_summary.json" in out
    summary = json.loads(ws.run_summary.read_text())
    assert list(summary["stages"]) == ["capture", "sfm"] and summary["stages"]["sfm"]["registered"] == 12
    assert "rotation_deg" not in summary["stages"]["sfm"]  # no ground truth: nothing compared
    assert _recorded(ws) == ["capture", "sfm"] and not (ws.root / ".m2m").exists()

    # part of the pipeline: finished stages are done earlier, an optional one without its inputs is skipped
    assert main(["run", "-w", str(ws.root), "--from", "sfm", "--until", "sfm"]) == 0
    assert "[1/1] sfm: done earlier" in capsys.readouterr().err
    assert main(["run", "-w", str(ws.root), "--from", "handeye", "--until", "handeye"]) == 0
    out, err = capsys.readouterr()
    assert "[1/1] handeye: skipped - no hand-eye images (handeye.images and handeye.joints are not set)" in err
    assert "  handeye    skipped: no hand-eye images" in out
    assert main(["run", "-w", str(ws.root), "--from", "align", "--until", "sfm"]) == 2
    assert "--from align comes after --until sfm" in capsys.readouterr().err

    # a board the capture never shows: the stage is named, and how to go on; nothing of it is written
    marker = tmp_path / "marker.json"
    marker.write_text(json.dumps({"type": "aruco", "size": 0.15, "id": 7, "dictionary": "DICT_6X6_250"}))
    text = ws.config_file.read_text()
    board_line = f"\nboard: {(SAMPLE / 'board.json').resolve()}\n"  # the pipeline's: at the top
    assert text.count(board_line) == 1
    ws.config_file.write_text(text.replace(board_line, f"\nboard: {marker}\n"))
    assert main(["run", "-w", str(ws.root), "--until", "align"]) == 2
    err = capsys.readouterr().err
    assert "m2m: error: align (stage 3 of 3, `m2m align-scene`): the target (ArUco marker id 7" in err
    assert "was detected in 0 of 12 keyframes" in err and f"run `m2m run -w {ws.root}` again" in err
    assert not ws.alignment_file.exists() and _recorded(ws) == ["capture", "sfm"]
    # the run's page says where and why it stopped, and shows what the finished stages made
    with chromium() as browser:
        text = open_page(browser, ws.report_html)
    assert "m2m run stopped at align (stage 3 of 3)" in text and "was detected in 0 of 12 keyframes" in text
    assert "capture done earlier (up to date) 12 keyframes" in text


def test_run_without_settings_says_how_to_write_them(tmp_path, capsys):
    assert main(["run", "-w", str(tmp_path / "ws")]) == 2
    assert "m2m.yaml not found: write the workspace's settings first, `m2m init -w" in capsys.readouterr().err
    assert not (tmp_path / "ws").exists()


SMALL = ["--capture.max-keyframes", "16", "--scene.iterations", "150", "--scene.checkpoint-every", "20",
         "--objects.matting.iterations", "500", "--objects.splat.iterations", "200", "--objects.voxel", "0.0025",
         "--world.max-mm", "10", "--generate.workers", "1"]  # fmt: skip


@pytest.mark.slow
def test_init_and_run_on_the_sample_killed_in_training_resumes_there_and_finishes(tmp_path, capsys, sample_dir):
    """`m2m init` + `m2m run` end to end on the sample's files, no ground truth given to the run (the calibrations
    are read from ground_truth.json as a user's calibration files), killed while the scene trains."""
    ws = Workspace(tmp_path / "ws")
    assert main(["init", "-w", str(ws.root), "--video", f"{S}/scene.mp4", "--board", f"{S}/board.json",
                 "--board-pose", f"{S}/ground_truth.json", "--intrinsics", f"{S}/ground_truth.json",
                 "--handeye-images", f"{S}/handeye/images", "--handeye-poses", f"{S}/handeye/joints.json",
                 "--handeye-board", f"{S}/handeye/board.json", "--handeye-intrinsics", f"{S}/ground_truth.json",
                 "--head-photo", f"{S}/head_view.png", "--objects", "banana", "--task", "grasp banana",
                 "--episodes", "2", *SMALL]) == 0  # fmt: skip
    capsys.readouterr()
    checkpoint = ws.state_dir / "txn" / "scene" / "staged" / "scene" / "checkpoint.pt"
    rc = _kill_once_recorded(["run", "-w", str(ws.root)], ws, "handeye", tmp_path / "killed.log", after=0.0,
                             ready=checkpoint.is_file)  # fmt: skip
    assert rc == -signal.SIGKILL and _recorded(ws) == ["capture", "sfm", "align", "handeye"]
    assert "[5/9] scene ...\n" in (tmp_path / "killed.log").read_text()

    assert main(["run", "-w", str(ws.root)]) == 0
    out, err = capsys.readouterr()
    with capsys.disabled():
        print("\n" + out)
    for i, stage in enumerate(["capture", "sfm", "align", "handeye"], 1):
        assert f"[{i}/9] {stage}: done earlier" in err
    assert "scene: resuming the interrupted run" in err and "scene: resuming from" in err
    assert "[6/9] head_view: " in err and "m2m run finished" in out
    summary = json.loads(ws.run_summary.read_text())
    assert summary["stages"]["scene"]["iterations"] == 150
    assert "PSNR" in summary["stages"]["head_view"]["line"] and "vs the photo" in summary["stages"]["head_view"]["line"]
    assert summary["stages"]["objects"]["line"] == "1 objects: banana"
    assert validate(ws.dataset_dir("grasp_banana")) == []
    assert _recorded(ws) == ["capture", "sfm", "align", "handeye", "scene", "head_view", "objects", "world", "generate"]
    assert not (ws.root / ".m2m").exists()
    assert PipelineConfig.load(ws.config_file).generate.task == ("grasp banana",)  # the run left its settings alone
    with chromium() as browser:  # the run's page: every picture and the dataset's preview load from disk
        text = open_page(browser, ws.report_html)
        videos = browser.execute_script("return [...document.querySelectorAll('video source')].map(s => s.src)")
    assert "m2m run finished" in text and "grasp banana" in text and "1 objects: banana" in text
    assert [Path(v).parent.name for v in videos] == ["grasp_banana"]

"""report.html, the run's page (``m2m run`` / ``m2m demo`` write it, ``m2m report`` rewrites it), opened from disk in
headless chromium: every image it shows loads, every video reaches its metadata, every file it links exists; on a
workspace of every stage (moved after writing: the links are relative) and on a run that failed half-way (it says
where and why). The workspaces are made up (records, pictures, a tiny H.264 video): no stage runs here."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from fixtures.browser import chromium, open_page
from mirage2matter.cli import main
from mirage2matter.errors import M2MError
from mirage2matter.stages import PIPELINE
from mirage2matter.stages.pipeline import PipelineConfig
from mirage2matter.video import write_video
from mirage2matter.workspace import Workspace

NAMES = [s.name for s in PIPELINE]


@pytest.fixture(scope="module")
def browser():
    with chromium() as driver:
        yield driver


# ---- made-up workspaces -------------------------------------------------------------------------------------------
def _picture(path: Path, w: int = 64, h: int = 48, seed: int = 0) -> Path:
    from PIL import Image

    path.parent.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    Image.fromarray(rng.integers(0, 255, (h, w, 3), dtype=np.uint8)).save(path)
    return path


def _video(path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    write_video(path, (np.full((32, 48, 3), 20 * i, np.uint8) for i in range(8)), fps=10, preset="ultrafast")
    return path


def _record(summary: dict) -> dict:
    return {"fingerprint": "0" * 16, "config": {}, "summary": summary, "seconds": 12.0}


HOSTILE = "<script>alert('x')</script> & \"quotes\""
ADVICE = "film the table's left side once more"
ROBOT_WARNING = "the robot's surface is 12 mm from the board's alignment: check align.capture_joints"


def _every_stage(root: Path) -> Workspace:
    """A workspace as a finished run leaves it: records, pictures and previews of every stage, a trained policy,
    its evaluation and the sim-to-real bench; hand-eye skipped by the plan."""
    ws = Workspace(root)
    for i in range(8):
        _picture(ws.capture_dir / f"frame_{i:06d}.jpg", seed=i)
    _picture(ws.overlay_png)
    _picture(ws.scene_dir / "heldout.png", 128, 48)
    ws.scene_metrics.write_text(json.dumps({"curve": [{"seconds": 60.0 * m, "psnr": 15 + 3 * m} for m in range(5)]}))
    _picture(ws.head_view_png, 128, 48)
    _picture(ws.object_dir("banana") / "figure.png", 96, 96)
    data = ws.dataset_dir("grasp_banana")
    (data / "meta").mkdir(parents=True)
    (data / "meta" / "info.json").write_text("{}")
    _video(data / "preview.mp4")
    _picture(data / "contact_sheet.png", 144, 32)
    _picture(ws.policy_dir("policy") / "loss_curve.png")
    (ws.policy_dir("policy") / "summary.json").write_text(json.dumps({"line": "policy: 2 datasets, loss 0.01"}))
    ev = ws.eval_dir("policy-hybrid-grasp_banana")
    _video(ev / "rollout.mp4")
    _picture(ev / "contact_sheet.png")
    (ev / "summary.json").write_text(json.dumps({"line": "'grasp banana' (hybrid): 7/10 = 70.0%"}))
    (ws.evals_dir / "sim2real.md").write_text("| policy | hybrid | real |\n| --- | --- | --- |\n| a | 0.7 | 0.6 |\n")
    summaries = {n: {"line": f"{n} line"} for n in NAMES}
    summaries["sfm"]["coverage"] = {"advice": [ADVICE]}
    summaries["align"] = {"robot": {"warning": ROBOT_WARNING}, "line": f"scale 0.25; WARNING: {ROBOT_WARNING}"}
    summaries["objects"] = {"objects": {"banana": {}}, "details": ["banana: 56 g"], "line": f"1 objects: {HOSTILE}"}
    summaries["generate"] = {"tasks": {"grasp banana": {"dataset": "/moved/away/datasets/grasp_banana", "episodes": 2,
                                                        "frames": 16, "success_rate": 1.0, "attempts": 2}},
                             "line": "1 dataset(s), 2 episodes"}  # fmt: skip
    records = {n: _record(s) for n, s in summaries.items() if n != "handeye"}
    records["train_policy/policy"] = _record({"line": "policy: 2 datasets, loss 0.01"})
    ws.record_file.write_text(json.dumps(records))
    run = {
        "command": "m2m demo",
        "started": "2026-12-01T10:00:00",
        "seconds": 600.0,
        "order": NAMES,
        "done_earlier": ["capture"],
        "warnings": {"world": ["banana: WARNING its reconstruction ends 3 mm from the table; moved onto it"]},
        "stages": {**summaries, "handeye": {"skipped": "no hand-eye images", "line": "skipped: no hand-eye images"}},
    }
    ws.demo_summary.write_text(json.dumps(run))
    return ws


def test_report_of_every_stage_opens_from_disk_after_the_workspace_moved(tmp_path, browser, capsys):
    ws = _every_stage(tmp_path / "ws")
    assert main(["report", "-w", str(ws.root)]) == 0
    assert "report.html" in capsys.readouterr().out
    moved = tmp_path / "elsewhere" / "ws copy"  # links relative and percent-encoded
    moved.parent.mkdir()
    shutil.move(ws.root, moved)
    raw = (moved / "report.html").read_text()
    assert "<script>alert" not in raw  # everything from the data escaped
    text = open_page(browser, moved / "report.html")
    assert "m2m demo finished" in text and "done earlier (up to date)" in text
    for n in NAMES:
        assert f"{n} line" in text or n in ("align", "objects", "generate", "handeye"), n
    assert f"1 objects: {HOSTILE}" in text  # shown as text
    warnings = text.split("Warnings", 1)[1].split("Stages", 1)[0]
    assert warnings.count(ROBOT_WARNING) == 1 and ADVICE in warnings  # one warning in a line and a field: once
    assert "world: its reconstruction ends 3 mm from the table" in warnings  # a warning the stage only logged
    steps = text.split("What to do next", 1)[1].split("Warnings", 1)[0]
    assert "handeye was skipped: no hand-eye images" in steps
    assert "grasp banana" in text and "2 episodes, 16 frames" in text and "7/10 = 70.0%" in text
    assert browser.execute_script("return document.querySelectorAll('video').length") == 2
    assert browser.execute_script("return document.querySelectorAll('svg polyline').length") == 1  # the PSNR curve


def test_a_video_the_browser_cannot_play_falls_back_to_its_poster(tmp_path, browser):
    ws = _every_stage(tmp_path / "ws")
    (ws.dataset_dir("grasp_banana") / "preview.mp4").write_bytes(b"not a video" * 100)
    assert main(["report", "-w", str(ws.root)]) == 0
    open_page(browser, ws.report_html)  # the broken one replaced by its linked poster, which loads
    srcs = browser.execute_script("return [...document.querySelectorAll('video source')].map(s => s.src)")
    assert len(srcs) == 1 and srcs[0].endswith("rollout.mp4")
    poster = browser.execute_script("return [...document.querySelectorAll('a[href$=\"preview.mp4\"] img')]"
                                    ".map(i => i.getAttribute('src'))")  # fmt: skip
    assert poster == ["datasets/grasp_banana/contact_sheet.png"]


def _fake_stages(fail_at: str, error: BaseException):
    """A ``run_stage`` whose stages write a few pictures and summaries, and ``fail_at`` raises ``error``."""

    def run_stage(stage, ws, cfg, log, ground_truth=None):
        if stage.name == fail_at:
            raise error
        if stage.name == "capture":
            for i in range(3):
                _picture(ws.capture_dir / f"frame_{i:06d}.jpg", seed=i)
        if stage.name == "sfm":
            log(f"sfm: WARNING: {ADVICE}")
        if stage.name == "align":
            _picture(ws.overlay_png)
        summary = {"line": f"{stage.name} done"}
        records = json.loads(ws.record_file.read_text()) if ws.record_file.is_file() else {}
        ws.record_file.write_text(json.dumps({**records, stage.name: _record(summary)}))
        return summary, False

    return run_stage


def _settings(tmp_path: Path) -> Workspace:
    ws = Workspace(tmp_path / "ws")
    cfg = PipelineConfig()
    cfg.capture.source = _video(tmp_path / "table.mp4")
    cfg.align.unaligned = True  # no board: hand-eye, head view, world and generate are skipped by the plan
    cfg.save(ws.config_file)
    return ws


def test_a_run_that_failed_half_way_says_where_and_why(tmp_path, browser, capsys, monkeypatch):
    ws = _settings(tmp_path)
    error = M2MError("train-scene: 2 of 3 keyframes are black; film again with the light on")
    monkeypatch.setattr("mirage2matter.stages.pipeline.run_stage", _fake_stages("scene", error))
    assert main(["run", "-w", str(ws.root)]) == 2
    err = capsys.readouterr().err
    assert "m2m: error: scene (stage 5 of 9, `m2m train-scene`): train-scene: 2 of 3 keyframes are black" in err
    assert f"where and why it stopped: {ws.report_html}" in err
    failed = json.loads(ws.run_summary.read_text())["failed"]  # `m2m report` finds the failure there
    assert failed["stage"] == "scene" and failed["index"] == 5 and "keyframes are black" in failed["error"]
    for again in (False, True):
        if again:
            ws.report_html.unlink()
            assert main(["report", "-w", str(ws.root)]) == 0
        text = open_page(browser, ws.report_html)
        assert "m2m run stopped at scene (stage 5 of 9)" in text
        where = text.split("Where and why it stopped", 1)[1].split("What to do next", 1)[0]
        assert "stage scene (m2m train-scene)" in where and "2 of 3 keyframes are black" in where
        assert f"run `m2m run -w {ws.root}` again: the finished stages are kept" in where
        steps = text.split("What to do next", 1)[1].split("Warnings", 1)[0]
        assert steps.strip().splitlines()[0].startswith("scene: Fix that")
        assert "handeye was skipped: no hand-eye images" in steps
        assert ADVICE in text.split("Warnings", 1)[1].split("Stages", 1)[0]
        table = text.split("Stages", 1)[1]
        assert "align done align done" in table and "scene failed train-scene: 2 of 3 keyframes are black" in table
        assert "objects not reached (the run stopped before it)" in table
    srcs = browser.execute_script("return [...document.images].map(i => i.getAttribute('src'))")
    assert srcs == [f"capture/frame_{i:06d}.jpg" for i in range(3)] + ["calib/overlay.png"]


def test_an_interrupted_run_and_a_bug_are_reported_and_go_on_as_before(tmp_path, capsys, monkeypatch):
    ws = _settings(tmp_path)
    monkeypatch.setattr("mirage2matter.stages.pipeline.run_stage", _fake_stages("sfm", KeyboardInterrupt()))
    assert main(["run", "-w", str(ws.root)]) == 130
    page = ws.report_html.read_text()
    assert "interrupted at sfm (stage 2 of 9)" in page and "the interrupted stage resumes" in page
    monkeypatch.setattr("mirage2matter.stages.pipeline.run_stage", _fake_stages("align", ZeroDivisionError("oops")))
    with pytest.raises(ZeroDivisionError):
        main(["run", "-w", str(ws.root)])
    page = ws.report_html.read_text()
    assert "stopped at align (stage 3 of 9)" in page and "ZeroDivisionError: oops" in page and "--debug" in page


def test_report_needs_a_workspace(tmp_path, capsys):
    assert main(["report", "-w", str(tmp_path / "none")]) == 2
    assert "not found" in capsys.readouterr().err
    assert main(["report", "-w", str(tmp_path)]) == 2
    assert "is not a workspace" in capsys.readouterr().err and not (tmp_path / "report.html").exists()

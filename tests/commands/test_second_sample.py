"""The second sample end to end (issue 18): made fresh with `m2m sample make` options (another seed and a random object
layout, the UR5e with the Franka hand, a phone-like lens with distortion), then `m2m init` WITHOUT the video camera's
intrinsics (SfM calibrates the phone lens itself) and `m2m run`, judged against the sample's ground truth: every
keyframe registered, the cameras within 0.2 deg / 2 mm of the truth after the board alignment (medians), every object
within issue 6's bars, the datasets valid with the UR5e's names and robot_type, and the UR5e's scripted success rates
in the twin of the run's world (`m2m task`, 20 seeds per task).

Slow: the sample (~2.5 min), the run (~10 min, half of it objects) and the task rates (~1 min) on 2 cores.

Measured on its first full run (2 shared cores; it stopped at the world stage, 26.5 min in): the sample, capture,
SfM 32/32 keyframes registered (reprojection 0.42 px; the lens found: fx 496.5 / fy 497.0 / cx 324.5 / cy 237.8 px,
k1 -0.159, k2 0.069 against 497.3 / 497.8 / 324.6 / 236.9, -0.16, 0.07), cameras vs ground truth 0.117 deg / 1.00 mm
(median), hand-eye 0.05 px leave-one-out; then objects (19.5 min): button passes issue 6 (chamfer 1.80 mm, volume
1.01, Gaussians to mesh 1.44 mm, masked PSNR 34.2 dB), but the croissant's masks are ~20 % smaller than its true
silhouette in every view (IoU 0.82 median; volume 0.84, Gaussians to mesh 3.98 mm from 23 opaque Gaussians) and the
banana's ~40 % larger (IoU 0.81, volume 1.16), so compose refused the world (Gaussians and mesh 4.0 mm apart > 3 mm).
That points at the mask provider on this layout rather than at the lens: the worst views are far from the image
border (>= 60 px), the button, seen through the same undistorted keyframes, is at IoU 0.95, and overlays of two views
show the croissant's mask losing a tip against the brown wood and the banana's taking in its shadow. So this test
FAILED there, at the objects stage.

Since (the objects stage on that run's workspace, same inputs, ~5 min for the three objects): the matting drops
Gaussians lying on the table and runs twice (the banana's masks took in the bare table inside its arc: IoU 0.81 ->
0.93, volume 1.16 -> 0.96, chamfer 1.20 mm, Gaussians to mesh 1.15 mm): button and banana pass every bar. The
croissant, the colour of the wood, does not: volume 0.85, its 184 opaque Gaussians 2.29 mm from its mesh (bar 2.0;
first run 3.98); it is drawn mostly by faint Gaussians (median opacity 0.014). Tried and not kept: carving the mesh
again with the retrained Gaussians' depth (``ObjectsConfig.recarve``: volume 0.93, but the bundled sample's croissant
1.90 -> 2.05 mm), random backgrounds behind the object 3DGS (2.01 mm here, the bundled croissant 2.85 mm),
lambda_opacity 0.1 (1.38 mm, volume 0.84), prune_inside 1.5 mm (2.03 mm). Closest: splat.min_opacity_init 0.3 (the
matting's faint Gaussians dropped before the object 3DGS) gives the croissant 1.23 mm / volume 0.898, and with recarve
1.49 mm / volume 1.004 (every bar), but then the banana's and the button's volumes are 1.10 / 1.12 here and the
bundled 24-keyframe banana's 1.106. Still xfail, strict.

2026-12-07, the carving's vote by height (``ObjectsConfig.skip_below``): this test failed on the button's volume
(1.123) before it; after it (15.8 min): button 1.051, banana 0.914, the croissant **0.884** (chamfer 2.15 mm; its masks
are tight and the vote's shell had made up for them): the xfail's reason is the croissant's volume now.

Run again with ``--runxfail`` at the end of that stop (a fresh sample, 10.5 min in all on 2 cores): `m2m run` went
through every stage in 8.9 min (scene held-out 32.0 dB, head view 21.4 dB against the photo, objects 4.5 min, the
world composed, the three datasets valid); 32/32 keyframes, the lens found again, cameras 0.117 deg / 1.00 mm; banana
and button pass every bar; the croissant misses only its volume, 0.843 (Gaussians to mesh 1.81 mm this time: the
object training is not bit-reproducible run to run).

Why the croissant: the mesh is carved with the object 3DGS's depth, and the renderers' depth (the alpha-weighted mean)
lay 1.5 mm (median) behind its surface: the croissant was a shell of faint Gaussians over opaque ones further in, so
carving took its front layer away (volume 1.03 from the masks alone, 0.85 with that depth). Since, the carving depth
is where a ray's opacity first reaches 0.2 (``ObjectsConfig.depth_opacity``, `gaussians/surface_depth.py`), the
matting's faint Gaussians are not carried into the object 3DGS (``splat.min_opacity_init`` 0.3) and Gaussians more
than 1.5 mm inside are pruned. Stage-only on that run's workspace: croissant volume 0.94, Gaussians to mesh 1.11 mm;
button 1.08 / 1.10 mm; banana 1.08 / 1.33 mm. On a fresh run (this test): every object passes (croissant volume 0.92,
chamfer 2.21 mm, Gaussians to mesh 1.52 mm; button 1.08, 1.85 mm, 1.21 mm; banana 1.07, 1.17 mm, 1.45 mm), cameras
0.117 deg / 1.00 mm, the UR5e 20/20 on every task; 12.9 min in all (`m2m run` 10.0: objects 5.5, scene 3.1, SfM 0.7).

On the first run, continued by hand past the objects (`m2m compose --max-mm 5`, then `m2m run`): the
three datasets (1 episode each) valid with the UR5e's names and robot_type, and the UR5e's rates over seeds
1000-1019: grasp banana, grasp croissant, press button and push croissant 20/20 each (0.14-0.69 s wall per episode).
"""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from fixtures.object_checks import issue6_failures, object_report
from mirage2matter.cli import main
from mirage2matter.datagen import task_slug
from mirage2matter.export import validate
from mirage2matter.inputs import read_yaml
from mirage2matter.robots import get_robot
from mirage2matter.stages import get_stage
from mirage2matter.stages.pipeline import PipelineConfig
from mirage2matter.workspace import Workspace

ROBOT = "ur5e"
SAMPLE_OPTIONS = ["--seed", "8", "--layout", "random", "--lens", "phone", "--robot", ROBOT]
# the keyframes at their default (60; with the UR5e in the video, 32 left the self-calibrated lens 0.34 % off in fy and
# the cameras 2.74 mm from the truth: 0.2 px corners cannot see a focal length error along the view axis; 40 gave
# 1.93 mm, 60 0.10 deg / 0.7 mm). The scene only feeds the world's look and the head-view check here, so 3 minutes;
# the objects at their defaults (issue 6)
BUDGET = ["--scene.minutes", "3", "--generate.workers", "1"]
GENERATED = ("grasp banana", "press button", "push croissant --direction 0,1 --distance 0.1")
RATES = {"grasp banana": 0.90, "grasp croissant": 0.90, "press button": 0.95,
         "push croissant --direction 0,1 --distance 0.1": 0.90}  # fmt: skip
EPISODES = 20


@pytest.mark.slow
# 2026-12-05, the UR5e standing in the video, moved half-way (stage by stage on one run): SfM 60/60, the lens found
# (fx 498.0 / fy 496.8 against 497.3 / 497.8), the cameras 0.107 deg / 4.10 mm from the truth but 0.40 px in the
# image (the check below); with a noise cluster no longer taking the button's name and the robot's pixels unknown
# rather than whole keyframes left out, the objects stage goes through: banana (volume 0.996) and croissant (0.940)
# pass every bar, the button's volume is 1.123 (bar 10 %; 1.117 with keyframes left out whole). After the carving's
# vote by height (2026-12-07): button 1.051, banana 0.914, croissant 0.884 (the reason below)
@pytest.mark.xfail(strict=True, reason="the croissant's volume under issue 6's 10 % (issue 62)")
def test_second_sample_init_and_run_self_calibrated_with_the_ur5e(tmp_path, capsys):
    times = {}
    t0 = time.perf_counter()
    sample = tmp_path / "sample"
    assert main(["sample", "make", str(sample), *SAMPLE_OPTIONS]) == 0
    times["sample"] = time.perf_counter() - t0
    gt = json.loads((sample / "ground_truth.json").read_text())
    lens = gt["camera"]
    assert lens["distortion"]["k1"] < -0.1 and gt["config"]["layout"] == "random" and gt["handeye"]["robot"] == ROBOT
    settings = read_yaml(sample / "m2m.yaml")
    names = settings["objects"]["names"]  # nearest the base first, as init takes them
    capture_joints = [str(q) for q in settings["capture_joints"]]  # the UR5e stands in the video
    moves = [w for frame, q in (settings.get("capture_moves") or {}).items()  # any move while filmed
             for w in ("--capture-move", str(frame), *map(str, q))]  # fmt: skip
    assert sorted(names) == ["banana", "button", "croissant"]

    s, ws = str(sample), Workspace(tmp_path / "ws")
    assert main(["init", "-w", str(ws.root), "--video", f"{s}/scene.mp4", "--board", f"{s}/board.json",
                 "--board-pose", f"{s}/ground_truth.json", "--handeye-images", f"{s}/handeye/images",
                 "--handeye-poses", f"{s}/handeye/joints.json", "--handeye-board", f"{s}/handeye/board.json",
                 "--handeye-intrinsics", f"{s}/ground_truth.json", "--head-photo", f"{s}/head_view.png",
                 "--robot", ROBOT, "--capture-joints", *capture_joints, *moves, "--objects", *names,
                 "--task", *GENERATED, "--episodes", "1",
                 *BUDGET]) == 0  # fmt: skip
    cfg = PipelineConfig.load(ws.config_file)
    assert cfg.sfm.intrinsics is None and cfg.world.robot == cfg.align.robot == ROBOT  # the lens is not given
    capsys.readouterr()
    t = time.perf_counter()
    assert main(["run", "-w", str(ws.root)]) == 0
    times["run"] = time.perf_counter() - t
    out, _ = capsys.readouterr()
    with capsys.disabled():
        print("\n" + out)
    summary = json.loads(ws.run_summary.read_text())["stages"]

    # every keyframe registered; the lens SfM found, against the true one
    assert summary["sfm"]["registered"] == summary["sfm"]["total"] == cfg.capture.max_keyframes, summary["sfm"]
    found = json.loads(ws.sfm_file.read_text())["cameras"][0]
    print("lens: true", {k: lens[k] for k in ("K", "distortion")})
    print("      SfM ", {k: found[k] for k in ("K", "distortion")})
    # the cameras against the ground truth, after the alignment to the base (the demo's comparison)
    cameras = get_stage("align").compare(ws, cfg.align, gt)
    px = _image_error_px(ws, gt)
    print(f"cameras vs ground truth: {cameras['rotation_deg']:.3f} deg / {cameras['translation_mm']:.2f} mm (median); "
          f"the workspace's points {px:.2f} px from where the true cameras see them (median)")
    # in pixels, not millimetres: a self-calibrated lens leaves the cameras' distance free by the focal length's error
    # (2026-12-05, the UR5e in the video: 4.10 mm, the board 3.06 mm low under the cameras' own best fit, yet 0.40 px;
    # the bundled sample's given lens: 1.56 mm, 0.25 px)
    assert cameras["rotation_deg"] <= 0.2 and px <= 1.0, (cameras, px)

    # issue 6's bars on every object
    failures = {}
    for name in names:
        report = object_report(ws.root, sample, gt, name)
        print(name, json.dumps({k: round(v, 4) if isinstance(v, float) else v for k, v in report.items()}))
        failures.update({name: issue6_failures(report)} if issue6_failures(report) else {})
    assert not failures, failures

    # the datasets: valid, with the UR5e's joints and robot_type
    spec = get_robot(ROBOT)
    for text in GENERATED:
        dataset = ws.dataset_dir(task_slug(text))
        assert validate(dataset) == [], text
        info = json.loads((dataset / "meta" / "info.json").read_text())
        assert info["robot_type"] == spec.robot_type == ROBOT
        assert info["features"]["observation.state"]["names"] == list(spec.state_names)
        assert info["features"]["action"]["names"] == [*spec.arm_joints, "gripper"]

    # the UR5e in the twin of the run's world: `m2m task`, 20 held-out seeds per task
    t = time.perf_counter()
    assert main(["task", "-w", str(ws.root), *RATES, "--episodes", str(EPISODES), "--seed", "1000"]) == 0
    times["tasks"] = time.perf_counter() - t
    results = dict(zip(RATES, json.loads(ws.task_summary.read_text())["tasks"], strict=True))
    got = {text: r["success_rate"] for text, r in results.items()}
    print(f"{ROBOT} success over {EPISODES} seeds:", got)
    times["total"] = time.perf_counter() - t0
    print("minutes:", {k: round(v / 60, 1) for k, v in times.items()})
    low = {text: rate for text, rate in got.items() if rate < RATES[text]}
    assert not low, (low, {text: results[text]["failures"] for text in low})


def _image_error_px(ws: Workspace, gt: dict) -> float:
    """Median over the keyframes of the median pixel distance between where each found camera (its pose in the base
    frame and the lens SfM found) and the true one (pose and lens) see points spread over the workspace: the table
    in front of the base and up to 30 cm above it."""
    from mirage2matter.capture import load_keyframes
    from mirage2matter.geometry.camera import Camera

    index = {k["file"]: k["frame_index"] for k in load_keyframes(ws.capture_dir)["keyframes"]}
    rng = np.random.default_rng(0)
    points = np.c_[rng.uniform(-0.1, 0.8, 3000), rng.uniform(-0.5, 0.5, 3000), rng.uniform(0.0, 0.3, 3000)]
    lens = {"K": gt["camera"]["K"], **({"distortion": gt["camera"]["distortion"]} if gt["camera"].get("distortion")
                                       else {})}  # fmt: skip
    out = []
    for cam in ws.posed_capture(frame="base").cameras:
        pose = {k: v for k, v in cam.to_json().items() if k != "distortion"}  # the true lens replaces the found one
        true = Camera.from_json({**pose, **lens, "T_world_cam": gt["frames"][index[cam.name]]["T_base_cam"]})
        uv, _ = cam.project(points)
        uv_true, z = true.project(points)
        seen = (z > 0) & np.all((uv_true >= 0) & (uv_true < [cam.width, cam.height]), axis=1)
        out.append(float(np.median(np.linalg.norm(uv[seen] - uv_true[seen], axis=1))))
    return float(np.median(out))

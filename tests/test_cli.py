"""The ``m2m`` command: render, bench render and demo, run in-process through ``main``.

Outputs are checked against the library called directly (``render``, ``read_ply``), and every
expected failure must exit with status 2, name the offending file or field, print no traceback and
leave no output (or temporary) file behind.
"""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import plyfile
import pytest
import torch
from PIL import Image

import mirage2matter
from fixtures.browser import chromium, open_page
from mirage2matter.bench.render import RESULT_KEYS, bench_render
from mirage2matter.cli import main
from mirage2matter.gaussians.ply import read_ply, write_ply
from mirage2matter.gaussians.render import render
from mirage2matter.gaussians.synthetic import orbit_cameras, tabletop_scene
from mirage2matter.geometry.camera import Camera, save_camera_json

W, H = 64, 48  # not square, so a width/height mix-up shows
BACKGROUND = (0.2, 0.4, 0.6)
# Right-multiplying an OpenCV camera-to-world pose by this gives the OpenGL one (flip y and z).
CV_TO_GL = np.diag([1.0, -1.0, -1.0, 1.0])


@pytest.fixture(scope="module")
def assets(tmp_path_factory: pytest.TempPathFactory) -> dict:
    d = tmp_path_factory.mktemp("cli_assets")
    g = tabletop_scene(3000, sh_degree=3, seed=1)
    write_ply(d / "scene.ply", g)
    cams = []
    for i, (viewmat, K) in enumerate(orbit_cameras(2, W, H, seed=3)):
        cams.append(Camera(K, np.linalg.inv(viewmat), W, H, name=f"cam{i}"))
    save_camera_json(d / "cam1.json", cams[1])
    return {
        "dir": d,
        "ply": d / "scene.ply",
        "camera": d / "cam1.json",
        "cams": cams,
        "gaussians": read_ply(d / "scene.ply"),
    }


def _direct_render(g, cam: Camera, background=BACKGROUND) -> tuple[np.ndarray, torch.Tensor]:
    with torch.no_grad():
        out = render(
            g,
            torch.from_numpy(cam.viewmat),
            torch.from_numpy(cam.K),
            cam.width,
            cam.height,
            background=torch.tensor(background, dtype=torch.float32),
            backend="cpu",
        )
    return out.rgb.clamp(0, 1).numpy(), out.depth


def _png(path: Path) -> np.ndarray:
    with Image.open(path) as im:
        assert im.mode == "RGB"
        return np.asarray(im).astype(np.float64) / 255.0


def _no_debris(d: Path) -> None:
    assert not [p.name for p in d.iterdir() if ".tmp-" in p.name]


# ---- m2m render -------------------------------------------------------------------------------------
def test_render_matches_library(assets: dict, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "view.png"
    bg = ",".join(map(str, BACKGROUND))
    rc = main(["render", str(assets["ply"]), "--camera", str(assets["camera"]), "--out", str(out)]
              + ["--backend", "cpu", "--background", bg])  # fmt: skip
    assert rc == 0
    stdout = capsys.readouterr().out
    assert str(out) in stdout and f"{W}x{H}" in stdout and "3,000 Gaussians" in stdout and "ms" in stdout
    got = _png(out)
    expected, _ = _direct_render(assets["gaussians"], assets["cams"][1])
    assert got.shape == (H, W, 3)
    assert np.abs(got - expected).max() <= 1 / 255 + 1e-6
    # The scene is really in view: not just background.
    assert np.abs(got - np.array(BACKGROUND)).max(axis=2).mean() > 0.1
    _no_debris(tmp_path)


def test_render_from_transforms_frame_matches_opencv_camera(assets: dict, tmp_path: Path) -> None:
    cams: list[Camera] = assets["cams"]
    K = cams[0].K
    transforms = {
        "fl_x": K[0, 0], "fl_y": K[1, 1], "cx": K[0, 2], "cy": K[1, 2], "w": W, "h": H,
        "frames": [
            {"file_path": f"images/{i:04d}.png", "transform_matrix": (c.T_world_cam @ CV_TO_GL).tolist()}
            for i, c in enumerate(cams)
        ],
    }  # fmt: skip
    tj = tmp_path / "transforms.json"
    tj.write_text(json.dumps(transforms), encoding="utf-8")
    common = [str(assets["ply"]), "--backend", "cpu"]
    assert main(["render", *common, "--camera", str(tj), "--frame", "0001", "--out", str(tmp_path / "frame.png")]) == 0
    assert main(["render", *common, "--camera", str(assets["camera"]), "--out", str(tmp_path / "cv.png")]) == 0
    from_frame, from_cv = _png(tmp_path / "frame.png"), _png(tmp_path / "cv.png")
    assert from_frame.shape == (H, W, 3)
    assert np.abs(from_frame - from_cv).max() <= 1 / 255 + 1e-6
    # The other frame is a different view: the frame choice matters.
    assert (
        main(["render", *common, "--camera", str(tj), "--frame", "images/0000.png", "--out", str(tmp_path / "f0.png")])
        == 0
    )
    assert np.abs(_png(tmp_path / "f0.png") - from_cv).mean() > 0.02


def test_render_scale_and_depth(assets: dict, tmp_path: Path) -> None:
    args = [
        "render",
        str(assets["ply"]),
        "--camera",
        str(assets["camera"]),
        "--backend",
        "cpu",
        "--background",
        "0.2,0.4,0.6",
    ]
    assert (
        main([*args, "--scale", "0.5", "--out", str(tmp_path / "half.png"), "--depth-out", str(tmp_path / "d.npy")])
        == 0
    )
    cam = assets["cams"][1].scaled(0.5)
    expected, depth = _direct_render(assets["gaussians"], cam)
    got = _png(tmp_path / "half.png")
    assert got.shape == (H // 2, W // 2, 3)
    assert np.abs(got - expected).max() <= 1 / 255 + 1e-6
    d = np.load(tmp_path / "d.npy")
    assert d.dtype == np.float32 and d.shape == (H // 2, W // 2)
    np.testing.assert_allclose(d, depth.numpy(), rtol=1e-6, atol=1e-6)
    assert (d > 0).any()
    # PNG depth: uint16 millimetres.
    assert main([*args, "--out", str(tmp_path / "full.png"), "--depth-out", str(tmp_path / "d.png")]) == 0
    with Image.open(tmp_path / "d.png") as im:
        mm = np.asarray(im).astype(np.float64)
    _, depth_full = _direct_render(assets["gaussians"], assets["cams"][1])
    assert mm.shape == (H, W)
    assert np.abs(mm - np.clip(depth_full.numpy() * 1000, 0, 65535)).max() <= 0.5 + 1e-3


def test_render_draws_the_camera_s_lens(assets: dict, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """A camera JSON with a lens renders through it: against a pinhole twice as wide read where OpenCV's
    undistortPoints puts each pixel's ray (colour bilinear, depth nearest), and far from the pinhole of its K."""
    import cv2
    from scipy.ndimage import map_coordinates

    lens = {"k1": -0.25, "k2": 0.05, "p1": 0.001, "p2": -0.0008, "k3": 0.0}
    cam = replace(assets["cams"][1], distortion=lens)
    save_camera_json(tmp_path / "lens.json", cam)
    # Gaussians a third as large: 3DGS's projection clamps a Gaussian's footprint past 1.3x the canvas's field of
    # view, so big ones near the border render a little differently on canvases of other sizes (as in gsplat)
    g = replace(assets["gaussians"], log_scales=assets["gaussians"].log_scales - float(np.log(3.0)))
    write_ply(tmp_path / "small.ply", g)
    args = ["render", str(tmp_path / "small.ply"), "--camera", str(tmp_path / "lens.json"), "--backend", "cpu"]
    assert main([*args, "--out", str(tmp_path / "lens.png"), "--depth-out", str(tmp_path / "d.npy")]) == 0
    assert "through the camera's lens" in capsys.readouterr().out
    got, depth = _png(tmp_path / "lens.png"), np.load(tmp_path / "d.npy")
    f = cam.fy
    wide = Camera(np.array([[f, 0, W], [0, f, H], [0, 0, 1.0]]), cam.T_world_cam, 2 * W, 2 * H)
    wide_rgb, wide_depth = _direct_render(g, wide, background=(0, 0, 0))
    u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    K_cv = cam.K - np.array([[0, 0, 0.5], [0, 0, 0.5], [0, 0, 0]])
    dist = np.array([lens[k] for k in ("k1", "k2", "p1", "p2", "k3")])
    tight = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-12)  # the default 5 iterations are ~0.1 px off
    xy = cv2.undistortPointsIter(np.c_[u.ravel(), v.ravel()][:, None], K_cv, dist, None, None, tight).reshape(-1, 2)
    rows, cols = f * xy[:, 1] + H - 0.5, f * xy[:, 0] + W - 0.5
    ref = np.stack([map_coordinates(wide_rgb[..., i], [rows, cols], order=1) for i in range(3)], -1).reshape(H, W, 3)
    ref_depth = map_coordinates(wide_depth.numpy(), [np.round(rows), np.round(cols)], order=0).reshape(H, W)
    inner = np.s_[2:-2, 2:-2]
    print(f"\nlens vs reference: colour {np.abs(got - ref)[inner].mean() * 255:.2f} levels (mean), depth "
          f"{np.median(np.abs(depth - ref_depth)) * 1000:.3f} mm (median)")
    assert np.abs(got - ref)[inner].mean() < 1.0 / 255 and np.median(np.abs(depth - ref_depth)) < 1e-6
    pinhole, _ = _direct_render(g, replace(cam, distortion={}), background=(0, 0, 0))
    assert np.abs(pinhole - ref)[inner].mean() > 10 * np.abs(got - ref)[inner].mean()
    # a fisheye seeing 180 deg has no pinhole to render through: a clear error, nothing written
    fisheye = replace(cam, K=np.diag([0.2, 0.2, 1.0]) @ cam.K, distortion={"k1": 0.0, "k2": 0.0, "k3": 0.0, "k4": 0.0},
                      distortion_model="fisheye")
    save_camera_json(tmp_path / "fisheye.json", fisheye)
    args[3] = str(tmp_path / "fisheye.json")
    assert main([*args, "--out", str(tmp_path / "fisheye.png")]) == 2
    assert "its lens sees too wide for a pinhole render" in capsys.readouterr().err
    assert not (tmp_path / "fisheye.png").exists()
    _no_debris(tmp_path)


def _write_point_cloud_ply(path: Path) -> None:
    v = np.zeros(5, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    plyfile.PlyData([plyfile.PlyElement.describe(v, "vertex")]).write(str(path))


@pytest.mark.parametrize(
    "case",
    ["missing_ply", "point_cloud_ply", "camera_missing_field", "missing_camera", "unknown_frame",
     "frame_without_transforms", "transforms_without_frame", "missing_out_dir", "bad_out_suffix"],
)  # fmt: skip
def test_render_bad_input(assets: dict, tmp_path: Path, capsys: pytest.CaptureFixture, case: str) -> None:
    ply, camera, out = assets["ply"], assets["camera"], tmp_path / "out.png"
    extra: list[str] = []
    transforms = tmp_path / "transforms.json"
    transforms.write_text(json.dumps({"fl_x": 50.0, "w": W, "h": H, "frames": [
        {"file_path": "images/a.png", "transform_matrix": np.eye(4).tolist()}]}), encoding="utf-8")  # fmt: skip
    if case == "missing_ply":
        ply = tmp_path / "nope.ply"
        expect = ["nope.ply", "not found"]
    elif case == "point_cloud_ply":
        ply = tmp_path / "points.ply"
        _write_point_cloud_ply(ply)
        expect = ["points.ply", "point cloud"]
    elif case == "camera_missing_field":
        camera = tmp_path / "cam_no_k.json"
        data = json.loads(assets["camera"].read_text())
        del data["K"]
        camera.write_text(json.dumps(data))
        expect = ["cam_no_k.json", "missing field", "K"]
    elif case == "missing_camera":
        camera = tmp_path / "nocam.json"
        expect = ["nocam.json", "not found"]
    elif case == "unknown_frame":
        camera, extra = transforms, ["--frame", "zzz_missing"]
        expect = ["transforms.json", "zzz_missing", "images/a.png"]
    elif case == "frame_without_transforms":
        extra = ["--frame", "0001"]
        expect = [assets["camera"].name, "frames", "drop --frame"]
    elif case == "transforms_without_frame":
        camera = transforms
        expect = ["transforms.json", "--frame"]
    elif case == "missing_out_dir":
        out = tmp_path / "no_such_dir" / "out.png"
        expect = ["no_such_dir", "does not exist"]
    else:
        out = tmp_path / "out.jpg"
        expect = ["out.jpg", ".png"]
    rc = main(["render", str(ply), "--camera", str(camera), "--out", str(out), "--backend", "cpu", *extra])
    err = capsys.readouterr().err
    assert rc == 2
    assert err.startswith("m2m: error: ") and "Traceback" not in err
    for word in expect:
        assert word in err, (word, err)
    assert not out.exists()
    _no_debris(tmp_path)


def test_usage_errors_return_2(assets: dict, capsys: pytest.CaptureFixture) -> None:
    assert main([]) == 2
    assert (
        main(
            ["render", str(assets["ply"]), "--camera", str(assets["camera"]), "--out", "x.png", "--background", "2,0,0"]
        )
        == 2
    )
    assert "R,G,B" in capsys.readouterr().err
    assert main(["render", "--help"]) == 0


# ---- m2m bench render ---------------------------------------------------------------------------------
def test_bench_render_function() -> None:
    r = bench_render(gaussians=2000, size=64, backend="cpu", views=2, repeats=1, warmup=1, log=None)
    assert tuple(r) == RESULT_KEYS
    assert r["backend"] == "cpu" and r["gaussians"] == 2000 and r["width"] == r["height"] == 64
    assert r["sh_degree"] == 3 and r["runs"] == 2
    assert 0 < r["ms_min"] <= r["ms_median"] <= r["ms_max"] < 60_000
    assert r["cameras_per_call"] == 1 and r["ms_per_camera"] == pytest.approx(r["ms_median"], abs=0.01)
    two = bench_render(gaussians=2000, size=64, backend="cpu", views=2, repeats=1, warmup=0, cameras_per_call=2,
                       log=None)  # fmt: skip
    assert two["cameras_per_call"] == 2 and two["ms_per_camera"] == pytest.approx(two["ms_median"] / 2, abs=0.01)
    with pytest.raises(ValueError, match="repeats"):
        bench_render(gaussians=10, size=8, repeats=0, log=None)
    with pytest.raises(TypeError, match="gausians"):
        bench_render(gausians=10, log=None)


def test_bench_render_cli_prints_json_last(capsys: pytest.CaptureFixture) -> None:
    rc = main(["bench", "render", "--gaussians", "2000", "--size", "32", "--backend", "cpu", "--sh-degree", "1"]
              + ["--views", "2", "--repeats", "2", "--warmup", "1"])  # fmt: skip
    assert rc == 0
    captured = capsys.readouterr()
    result = json.loads(captured.out.strip().splitlines()[-1])
    assert tuple(result) == RESULT_KEYS
    assert result["runs"] == 4 and result["sh_degree"] == 1 and result["width"] == 32
    assert "bench render" in captured.err  # progress goes to stderr


@pytest.mark.skipif(torch.cuda.is_available(), reason="checks the no-GPU message")
def test_bench_cuda_without_gpu_is_a_clear_error(capsys: pytest.CaptureFixture) -> None:
    assert main(["bench", "render", "--gaussians", "10", "--size", "8", "--backend", "cuda"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("m2m: error: --backend cuda") and "Traceback" not in err


# ---- m2m demo ------------------------------------------------------------------------------------------------
def test_demo_first_stages_and_resume(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """The demo's first stages on the sample (the whole run is `make demo`)."""
    ws = tmp_path / "ws"
    args = ["demo", "-w", str(ws), "--capture.max-keyframes", "16", "--until", "handeye"]
    assert main(args) == 0
    out, err = capsys.readouterr()
    s = json.loads((ws / "demo_summary.json").read_text())
    assert list(s["stages"]) == ["capture", "sfm", "align", "handeye"]
    st = s["stages"]
    assert st["capture"]["keyframes"] == 16 and st["sfm"]["registered"] >= 14
    assert st["sfm"]["rotation_deg"] < 0.5  # vs the sample's ground truth
    # the sample's robot moves half-way: SfM keeps it out of the features after the move (unmasked, on these 16
    # keyframes: 4.2 deg, the cameras 10.6 mm off after the alignment; masked 0.13 deg, 2.1 mm)
    masks = json.loads((ws / "sfm" / "robot_masks.json").read_text())
    assert len(masks["masked"]) >= 6 and "the moved robot masked out of" in st["sfm"]["line"]
    # its points then come from the first pose alone (10 of them on these keyframes): the logged move counts it seen
    assert st["align"]["robot"]["seen"] and "in the keyframes" in st["align"]["line"]
    assert st["align"]["translation_mm"] < 5.0 and abs(st["align"]["scale"]) > 0
    assert st["handeye"]["rotation_deg"] < 0.1 and st["handeye"]["translation_mm"] < 1.0
    assert "[4/4] handeye:" in err and "m2m demo finished" in out
    for rel in ("capture/keyframes.json", "sfm/sfm.json", "calib/sim3_sfm_to_base.json", "calib/handeye.json"):
        assert (ws / rel).is_file(), rel
    assert "max_keyframes: 16" in (ws / "m2m.yaml").read_text()  # the settings it ran with

    # a rerun resumes: finished stages are skipped, not redone; the demo's workspace is one `m2m run` continues
    assert main(args) == 0
    err = capsys.readouterr().err
    assert err.count("done earlier") == 4
    assert main(["run", "-w", str(ws), "--until", "handeye"]) == 0
    out, err = capsys.readouterr()
    assert err.count("done earlier") == 4 and "m2m run finished" in out and (ws / "run_summary.json").is_file()
    # a changed setting reruns that stage, and the next because its input changed
    assert main(["demo", "-w", str(ws), "--capture.max-keyframes", "12", "--until", "sfm"]) == 0
    err = capsys.readouterr().err
    assert err.count("done earlier") == 0 and "12 keyframes" in err
    # a stage command on the demo's workspace uses the demo's settings (m2m.yaml): align is up to date only after
    # it ran on the new SfM
    assert main(["align-scene", "-w", str(ws)]) == 0
    assert "up to date" not in capsys.readouterr().out
    assert main(["align-scene", "-w", str(ws)]) == 0
    assert "up to date" in capsys.readouterr().out
    # the run's page (the demo wrote it; `m2m report` again, now with align): every picture loads, every link exists
    assert 'm2m demo</code> <span class="ok">finished' in (ws / "report.html").read_text()
    assert main(["report", "-w", str(ws)]) == 0
    with chromium() as browser:
        text = open_page(browser, ws / "report.html")
        images = browser.execute_script("return [...document.images].map(i => i.getAttribute('src'))")
    assert "m2m demo finished" in text and "align done (not part of the last run)" in text
    assert "calib/overlay.png" in images and len(images) == 7  # 6 keyframes and the alignment's overlay


def test_demo_workspace_is_a_file(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    f = tmp_path / "ws"
    f.write_text("not a folder")
    assert main(["demo", "-w", str(f)]) == 2
    assert "not a folder" in capsys.readouterr().err


# ---- the installed entry points ------------------------------------------------------------------------------
def test_entry_points_and_light_import() -> None:
    m2m = Path(sys.executable).parent / "m2m"
    if not m2m.exists():
        pytest.skip("m2m console script not installed next to this interpreter")
    r = subprocess.run([str(m2m), "--version"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and mirage2matter.__version__ in r.stdout
    r = subprocess.run([sys.executable, "-m", "mirage2matter", "--help"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and "render" in r.stdout and "demo" in r.stdout
    # `m2m --help` stays fast: the CLI module does not import torch or numba.
    code = "import sys, mirage2matter.cli; print(sorted(m for m in ('torch', 'numba') if m in sys.modules))"
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and r.stdout.strip() == "[]"


def test_the_command_line_loads_neither_gymnasium_nor_generation() -> None:
    """`m2m --help` loads no gymnasium (~90 ms) and no generation library (datagen, the benchmarks: they load in the
    commands that run them), and the twin's id is still registered once gymnasium is imported after the CLI."""
    code = (
        "import sys, mirage2matter.cli as cli; cli.build_parser(None); "
        "print(sorted(m for m in ('gymnasium', 'mirage2matter.datagen', 'mirage2matter.env.twin_env') "
        "if m in sys.modules)); "
        "import gymnasium, mirage2matter.env; print(mirage2matter.env.ENV_ID in gymnasium.registry)"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == ["[]", "True"]


@pytest.mark.slow
def test_bench_train_on_fox_prints_json_last(fox_dir: Path, capsys: pytest.CaptureFixture) -> None:
    assert main(["bench", "train", "--data", str(fox_dir), "--minutes", "1", "--downscale", "8"]) == 0
    result = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    keys = {"psnr_heldout", "ssim_heldout", "iterations", "gaussians", "minutes", "budget_used", "backend"}
    assert set(result) == keys and 0.9 <= result["budget_used"] <= 1.0
    assert result["psnr_heldout"] > 18.0 and result["iterations"] > 50


def test_a_setting_given_on_the_command_line_wins_over_an_exclusive_one_in_m2m_yaml(capsys):
    """Issue 65: after `m2m sfm --from-transforms T`, `m2m sfm --intrinsics K` runs with K (T, from m2m.yaml, dropped
    and said so), not T again; both on one command line are an error naming both."""
    import argparse
    from pathlib import Path

    from mirage2matter.cli import _command_line_wins
    from mirage2matter.errors import M2MError
    from mirage2matter.stages import sfm

    saved = sfm.Config(from_transforms=Path("T.json"))
    cfg = _command_line_wins(sfm.Config(from_transforms=Path("T.json"), intrinsics=Path("K.json")),
                             argparse.Namespace(intrinsics=Path("K.json")))  # fmt: skip
    assert cfg.intrinsics == Path("K.json") and cfg.from_transforms is None
    assert "--intrinsics given: from_transforms of m2m.yaml dropped" in capsys.readouterr().err
    assert _command_line_wins(saved, argparse.Namespace()) == saved  # nothing given: m2m.yaml as it is
    with pytest.raises(M2MError, match="intrinsics and from_transforms are both given"):
        sfm.Config(from_transforms=Path("T.json"), intrinsics=Path("K.json")).validate()

"""The sample maker's lens: a distorted camera's image resampled from a wider pinhole render (sample.lens), the
`--lens` / `--layout` options and what a sample made with them says about itself."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from mirage2matter.geometry.camera import Camera
from mirage2matter.render.lens import lens_rays, pinhole_cover, resample_through_lens
from mirage2matter.sample.lens import LENSES

PHONE = LENSES["phone"]


def _pattern(xy: np.ndarray) -> np.ndarray:
    """A smooth scene painted on normalised pinhole coordinates [..., 2] -> RGB levels [..., 3] in 20..235."""
    x, y = xy[..., 0], xy[..., 1]
    return np.stack([128 + 100 * np.sin(9 * x + 2 * y), 128 + 100 * np.cos(7 * y - 3 * x),
                     128 + 100 * np.sin(5 * x * y + 4 * x)], axis=-1)  # fmt: skip


def test_the_phone_lens_is_a_phone_like_radial_tangential_lens():
    cam = PHONE.camera(640, 480)
    assert cam.has_distortion and cam.distortion_model == "opencv"
    assert -0.2 <= cam.distortion["k1"] <= -0.1 and 0 < abs(cam.distortion["p1"]) < 0.002
    assert abs(cam.cx - 320) > 2 and abs(cam.cy - 240) > 2  # the principal point is not the image centre
    # barrel: the image corners see further out than a pinhole's (by ~35 px here), the centre the same
    corner = np.array([[0.5, 0.5]])
    assert np.linalg.norm(cam.undistort_pixels(corner) - corner) > 30
    centre = np.array([[cam.cx, cam.cy]])
    assert np.abs(cam.undistort_pixels(centre) - centre).max() < 1e-9


def test_lens_rays_are_the_rays_the_lens_images_at_each_sample():
    cam = PHONE.camera(64, 48)
    rays = lens_rays(cam, supersample=2)
    assert rays.shape == (96, 128, 2)
    # sample (row i, column j) sits at pixel ((j + 0.5) / 2, (i + 0.5) / 2); the lens images its ray there
    i, j = np.array([0, 47, 95, 10]), np.array([0, 64, 127, 3])
    xy = rays[i, j]
    uv_pinhole = np.c_[cam.fx * xy[:, 0] + cam.cx, cam.fy * xy[:, 1] + cam.cy]
    np.testing.assert_allclose(cam.distort_pixels(uv_pinhole), np.c_[(j + 0.5) / 2, (i + 0.5) / 2], atol=1e-8)


def test_an_image_resampled_through_the_lens_shows_each_pixel_its_own_ray():
    """A scene painted on ray directions, rendered by a wide centred pinhole, resampled through the lens: every pixel
    reads the paint of its own rays (an error in the principal point, a focal or the distortion's direction would be
    off by many levels)."""
    cam = PHONE.camera(160, 120)
    cam = replace(cam, K=np.diag([0.25, 0.25, 1.0]) @ PHONE.camera(640, 480).K)  # the phone lens at 1/4 size
    rays = lens_rays(cam, supersample=2)
    focal = 130.0
    w, h = pinhole_cover(rays, focal, (cam.width, cam.height))
    assert (w - cam.width) % 2 == 0 and (h - cam.height) % 2 == 0 and w > cam.width and h > cam.height
    # the wide pinhole render: its pixel centres' rays
    u, v = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    wide = _pattern(np.stack([(u - w / 2) / focal, (v - h / 2) / focal], axis=-1))
    out = resample_through_lens(np.round(wide).astype(np.uint8), focal, rays)
    assert out.shape == (120, 160, 3) and out.dtype == np.uint8
    expected = _pattern(rays).reshape(120, 2, 160, 2, 3).mean(axis=(1, 3))
    err = np.abs(out.astype(float) - expected)
    assert np.median(err) < 0.5 and err.max() < 2.0, (np.median(err), err.max())  # measured 0.25 / 0.93
    # the same focal lengths without the lens, principal point at the image centre: visibly wrong
    K = np.array([[cam.fx, 0.0, 80.0], [0.0, cam.fy, 60.0], [0.0, 0.0, 1.0]])
    pinhole = lens_rays(Camera(K, np.eye(4), 160, 120))
    wrong = np.abs(_pattern(pinhole).reshape(120, 2, 160, 2, 3).mean(axis=(1, 3)) - expected)
    assert np.median(wrong) > 3.0  # measured 3.9 levels
    with pytest.raises(ValueError, match="render it wider"):
        resample_through_lens(np.zeros((cam.height, cam.width, 3), np.uint8), focal, rays)


def test_the_command_line_offers_every_lens_and_layout():
    import argparse

    from mirage2matter.cli import build_parser
    from mirage2matter.commands.sample import SampleMakeConfig
    from mirage2matter.configs import from_flags
    from mirage2matter.world.sample_assets import LAYOUTS

    def sub(parser: argparse.ArgumentParser, name: str) -> argparse.ArgumentParser:
        return next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices[name]

    parser = build_parser(None)
    sample = sub(sub(parser, "sample"), "make")
    options = {a.dest: a for a in sample._actions}
    assert tuple(options["lens"].choices) == tuple(LENSES) and tuple(options["layout"].choices) == LAYOUTS
    # the defaults are the command's Config's (argparse holds none of its own)
    cfg = from_flags(SampleMakeConfig, parser.parse_args(["sample", "make", "out"]))
    assert cfg.lens == "pinhole" and cfg.layout == "nominal"


def test_a_default_samples_settings_and_ground_truth_record_no_new_fields(tmp_path):
    """The default sample's ground truth keeps its fields (no lens, no layout) and its m2m.yaml is the bundled one;
    a sample with the phone lens, a random layout and the UR5e says so, and its m2m.yaml hands SfM no intrinsics and
    the UR5e's capture joints; an empty table's has none and says why."""
    from mirage2matter.inputs import read_yaml
    from mirage2matter.sample.inspect import BUNDLED_SAMPLE
    from mirage2matter.sample.make import (
        SampleConfig,
        _config_json,
        _write_settings,
        with_layout,
        with_lens,
        with_robot_in_view,
    )
    from mirage2matter.stages.pipeline import PipelineConfig

    bundled = with_robot_in_view(SampleConfig())
    default = _config_json(bundled)
    assert "lens" not in default and "layout" not in default
    _write_settings(tmp_path / "default.yaml", bundled, ["banana", "croissant", "button"])
    assert (tmp_path / "default.yaml").read_bytes() == (BUNDLED_SAMPLE / "m2m.yaml").read_bytes()

    config = replace(with_layout(with_lens(with_robot_in_view(SampleConfig(seed=8)), "phone"), "random"), robot="ur5e")
    recorded = json.loads(json.dumps(_config_json(config)))
    assert recorded["lens"]["name"] == "phone" and recorded["layout"] == "random" and recorded["robot"] == "ur5e"
    ur5e_q = (-1.9, -1.57, 1.57, -1.57, -1.57, 0.0)
    _write_settings(tmp_path / "m2m.yaml", config, ["croissant", "button", "banana"], ur5e_q)
    settings = read_yaml(tmp_path / "m2m.yaml")
    assert "intrinsics" not in settings.get("sfm", {}) and settings["handeye"]["intrinsics"] == "ground_truth.json"
    assert settings["objects"]["names"] == ["croissant", "button", "banana"]
    assert settings["robot"] == "ur5e" and "align" not in settings  # one robot for the whole pipeline
    assert settings["capture_joints"] == list(ur5e_q)  # the pipeline's, at the top as well
    text = (tmp_path / "m2m.yaml").read_text()
    assert "SfM calibrates the camera itself" in text and text.count("The robot stands in the video") == 1

    _write_settings(tmp_path / "empty.yaml", SampleConfig(), ["banana", "croissant", "button"])
    empty = (tmp_path / "empty.yaml").read_text()
    assert not {"capture_joints", "capture_moves"} & set(read_yaml(tmp_path / "empty.yaml"))
    assert "--empty-table" in empty and "The robot stands in the video" not in empty
    (tmp_path / "board.json").write_text("{}")  # the stages' inputs need not exist to parse the settings
    assert PipelineConfig.load(tmp_path / "m2m.yaml").sfm.intrinsics is None

"""``m2m intrinsics``: a calibration file shown in our convention, and converted to our JSON."""

from __future__ import annotations

import json

from mirage2matter.cli import main
from mirage2matter.geometry.camera import load_intrinsics


def test_shows_our_convention_and_converts(tmp_path, capsys):
    rs = tmp_path / "rs.json"  # RealSense: centres at integers
    rs.write_text(json.dumps({"width": 640, "height": 480, "fx": 400.0, "fy": 400.0, "ppx": 319.5, "ppy": 239.5,
                              "model": "Brown Conrady", "coeffs": [0.1, -0.2, 0.0, 0.0, 0.05]}))  # fmt: skip
    assert main(["intrinsics", str(rs)]) == 0
    out = capsys.readouterr().out
    assert "cx 320.000  cy 240.000" in out and "radial-tangential" in out
    # a centred pinhole's horizontal fov is 2 atan(320 / 400) = 77.3 deg; the lens widens it
    assert "horizontal 7" in out or "horizontal 8" in out
    assert main(["intrinsics", str(rs), "--json"]) == 0
    ours = tmp_path / "ours.json"
    ours.write_text(capsys.readouterr().out)
    a, b = load_intrinsics(rs), load_intrinsics(ours)
    assert (a.K == b.K).all() and a.distortion == b.distortion


def test_fisheye_beyond_180_and_a_bad_file(tmp_path, capsys):
    txt = tmp_path / "cameras.txt"
    txt.write_text("1 OPENCV_FISHEYE 1000 1000 250 250 500 500 0 0 0 0\n")  # edges 2 rad off the axis
    assert main(["intrinsics", str(txt)]) == 0
    out = capsys.readouterr().out
    assert "equidistant fisheye" in out and "horizontal 229.2 deg" in out and "diagonal 324.1 deg" in out
    bad = tmp_path / "what.json"
    bad.write_text("{}")
    assert main(["intrinsics", str(bad)]) == 2
    assert str(bad) in capsys.readouterr().err

"""The input readers and checks every command shares (mirage2matter.inputs)."""

import cv2
import numpy as np
import pytest

from mirage2matter.inputs import (
    InputError,
    check_image_size,
    check_intrinsics,
    check_joints,
    check_mesh,
    read_image_rgb,
    read_json,
    read_yaml,
    read_yaml_lines,
)


def test_sixteen_bit_images_are_scaled_not_clipped(tmp_path):
    """A 16-bit photo (PNG straight from a machine-vision camera) reads as the 8-bit image it shows: PIL's
    convert("RGB") clipped it to white."""
    rng = np.random.default_rng(0)
    rgb8 = rng.integers(0, 256, (20, 30, 3), dtype=np.uint8)
    rgb16 = rgb8.astype(np.uint16) * 257  # the same picture at 16 bits
    cv2.imwrite(str(tmp_path / "a16.png"), rgb16[..., ::-1])
    cv2.imwrite(str(tmp_path / "a8.png"), rgb8[..., ::-1])
    cv2.imwrite(str(tmp_path / "grey16.png"), rgb16[..., 0])
    cv2.imwrite(str(tmp_path / "rgba.png"), np.dstack([rgb8[..., ::-1], np.full((20, 30), 255, np.uint8)]))
    assert np.array_equal(read_image_rgb(tmp_path / "a16.png"), rgb8)
    assert np.array_equal(read_image_rgb(tmp_path / "a8.png"), rgb8)
    assert np.array_equal(read_image_rgb(tmp_path / "grey16.png"), np.repeat(rgb8[..., :1], 3, axis=2))
    assert np.array_equal(read_image_rgb(tmp_path / "rgba.png"), rgb8)
    (tmp_path / "text.png").write_text("not an image")
    with pytest.raises(InputError, match="cannot be read as an image"):
        read_image_rgb(tmp_path / "text.png")


def test_json_and_yaml_readers_refuse_what_would_exhaust_the_machine(tmp_path):
    (tmp_path / "deep.json").write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(InputError, match="nested deeper"):
        read_json(tmp_path / "deep.json", expect=None)
    (tmp_path / "list.json").write_text("[1, 2]")
    with pytest.raises(InputError, match="must hold an object"):
        read_json(tmp_path / "list.json")
    bomb = "a: &a [x, x]\nb: &b [*a, *a]\nc: [*b, *b]\n"
    (tmp_path / "bomb.yaml").write_text(bomb)
    with pytest.raises(InputError, match=r"aliases \(\*a\) are not supported \(line 2\)"):
        read_yaml(tmp_path / "bomb.yaml")
    (tmp_path / "big.yaml").write_bytes(b"# " + b"x" * (17 << 20))
    with pytest.raises(InputError, match="MiB"):
        read_yaml(tmp_path / "big.yaml")
    (tmp_path / "ok.yaml").write_text("a: [1, 2]\nb: {c: d}\n")
    assert read_yaml(tmp_path / "ok.yaml") == {"a": [1, 2], "b": {"c": "d"}}
    (tmp_path / "empty.yaml").write_text("")
    assert read_yaml(tmp_path / "empty.yaml") == {}
    # a character YAML does not allow (found by tests/test_fuzz.py: a file holding one NUL byte raised yaml's error)
    for name, data in (("nul.yaml", b"\x00"), ("bell.yaml", b"a: 1\nb: \x07\n")):
        (tmp_path / name).write_bytes(data)
        with pytest.raises(InputError, match=rf"{name} is not valid YAML: unacceptable character"):
            read_yaml(tmp_path / name)
        with pytest.raises(InputError, match="not valid YAML"):
            read_yaml_lines(tmp_path / name)


def test_camera_checks():
    K = [[500, 0, 320], [0, 500, 240], [0, 0, 1]]
    assert check_intrinsics(K, "cam").shape == (3, 3)
    for bad, msg in (([[0, 0, 0], [0, 0, 0], [0, 0, 1]], "positive"), ([[1, 0, 0], [0, 1, 0]], "3x3"),
                     ([[np.nan, 0, 0], [0, 1, 0], [0, 0, 1]], "finite")):  # fmt: skip
        with pytest.raises(InputError, match=msg):
            check_intrinsics(bad, "cam")
    assert check_image_size(640.0, "cam", "width") == 640
    for bad in (0, -3, 1.5, True, "640", 10**9, float("inf")):
        with pytest.raises(InputError, match="width"):
            check_image_size(bad, "cam", "width")


def test_mesh_and_joint_checks():
    tet_v = [[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0], [0, 0, 0.1]]
    tet_f = [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]
    check_mesh(tet_v, tet_f, "tet")
    with pytest.raises(InputError, match="at least 4 triangles"):
        check_mesh(tet_v, tet_f[:1], "tet")
    with pytest.raises(InputError, match="refers to vertex 9"):
        check_mesh(tet_v, [*tet_f[:3], [1, 2, 9]], "tet")
    with pytest.raises(InputError, match="across"):
        check_mesh(np.asarray(tet_v) * 1e3, tet_f, "tet")
    names = ("j1", "j2")
    limits = np.array([[-1.0, 1.0], [-2.0, 2.0]])
    assert check_joints([0.5, -1.5], names, limits, "q").tolist() == [0.5, -1.5]
    for bad, msg in (([0.5], "1 joint value"), ([0.5, float("nan")], "finite"), ([0.5, 2.5], "j2 = 2.5 is outside"),
                     (5, "1 joint value")):  # fmt: skip
        with pytest.raises(InputError, match=msg):
            check_joints(bad, names, limits, "q")

"""``m2m robot``: the registered robots, one robot with the numbers its model gave, a bad spec file named."""

import json

import pytest

from mirage2matter.cli import main
from mirage2matter.robots import ROBOTS, get_robot
from mirage2matter.robots.model import genesis_assets_dir

pytestmark = pytest.mark.skipif(genesis_assets_dir() is None, reason="no Genesis assets")


def test_lists_and_shows_robots(capsys):
    assert main(["robot"]) == 0
    out = capsys.readouterr().out
    assert all(name in out for name in ROBOTS)
    assert main(["robot", "ur5e", "--json"]) == 0
    shown = json.loads(capsys.readouterr().out)
    spec = get_robot("ur5e")
    assert shown["velocity_limit"] == list(spec.velocity_limit) and shown["state_names"] == list(spec.state_names)
    assert shown["provenance"]["acceleration_limit"] == "default" and shown["reach"] == pytest.approx(spec.reach)
    assert main(["robot", "panda"]) == 0
    out = capsys.readouterr().out
    assert "joint7" in out and "frames       EE: hand +103.4 mm along z; flange: link7 +107.0 mm along z;" in out
    assert main(["robot", "panda", "--json"]) == 0  # its named frames too
    assert json.loads(capsys.readouterr().out)["frames"]["EE"] == {"link": "hand", "xyz": [0.0, 0.0, 0.1034],
                                                                   "rpy": [0.0, 0.0, 0.0]}  # fmt: skip
    assert main(["robot", "--json"]) == 0
    assert set(json.loads(capsys.readouterr().out)) == set(ROBOTS)


def test_a_bad_spec_file_is_a_clear_error(tmp_path, capsys):
    bad = tmp_path / "arm.yaml"
    bad.write_text("name: arm\nmodel: urdf/kuka_iiwa/model.urdf\narm: {joints: [lbr_iiwa_joint_1], home: [0]}\n")
    assert main(["robot", str(bad)]) == 2
    err = capsys.readouterr().err
    assert f"{bad}: gripper.joints: missing" in err and "needs a gripper" in err
    assert main(["robot", "ur42"]) == 2
    assert "unknown robot 'ur42'" in capsys.readouterr().err

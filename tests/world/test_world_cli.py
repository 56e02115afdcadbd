"""m2m world (edits, check) / m2m task / m2m compose: wiring and clear errors (no Genesis build here)."""

import shutil

import numpy as np

from mirage2matter.cli import main
from mirage2matter.gaussians.ply import read_ply
from mirage2matter.world import load_world


def test_compose_move_and_bad_tasks(sample_ws, tmp_path, capsys):
    ws = tmp_path / "ws"
    shutil.copytree(sample_ws, ws, symlinks=True)
    assert main(["world", "check", "-w", str(ws)]) == 0
    out = capsys.readouterr().out
    assert "median Gaussian-to-mesh distance" in out and (ws / "world" / "world.ply").is_file()
    n = len(read_ply(ws / "world" / "world.ply"))

    before = load_world(ws / "world").object("banana").placement.translation.copy()
    assert main(["world", "move", "-w", str(ws), "--name", "banana", "--by", "0,-0.03,0"]) == 0
    after = load_world(ws / "world").object("banana").placement.translation
    assert np.allclose(after - before, [0, -0.03, 0])
    assert (
        main(["world", "duplicate", "-w", str(ws), "--name", "croissant", "--as", "croissant2", "--to", "0.3,-0.35,0"])
        == 0
    )
    assert len(read_ply(ws / "world" / "world.ply")) > n
    assert main(["world", "delete", "-w", str(ws), "--name", "croissant2"]) == 0
    assert len(read_ply(ws / "world" / "world.ply")) == n
    capsys.readouterr()

    assert main(["world", "move", "-w", str(ws), "--name", "kiwi", "--to", "0.5,0,0"]) == 2
    assert "no object named 'kiwi'" in capsys.readouterr().err
    assert main(["task", "-w", str(ws), "lift banana"]) == 2
    assert "unknown task 'lift'" in capsys.readouterr().err
    assert main(["task", "-w", str(ws), "grasp kiwi"]) == 2
    assert "no object named 'kiwi'" in capsys.readouterr().err
    assert main(["compose", "-w", str(tmp_path / "nowhere")]) == 2
    assert "run `m2m calibrate-handeye" in capsys.readouterr().err

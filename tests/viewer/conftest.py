"""A small workspace for the viewer tests: the sample's ground-truth world (coarse), the robot's captured look (its
mesh look as per-link Gaussians, coarse), six keyframe cameras with pictures, the board, and a three-episode
dataset of the world's robot; and a headless Chromium (skipped where it is not installed)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from fixtures.browser import chromium
from fixtures.viewer_workspace import add_dataset, add_keyframes, add_robot_look
from mirage2matter.workspace import Workspace


@pytest.fixture(scope="session")
def viewer_ws_template(sample_world_ws, tmp_path_factory) -> Path:
    src = sample_world_ws(gaussians_per_object=3000, scene_density_per_m2=4000.0, max_collision_parts=2)
    root = tmp_path_factory.mktemp("viewer") / "ws"
    shutil.copytree(src, root)
    ws = Workspace(root)
    add_keyframes(ws)
    add_robot_look(ws)
    add_dataset(ws)
    return root


@pytest.fixture
def viewer_ws(viewer_ws_template, tmp_path) -> Path:
    """A fresh copy per test: the tests write world.yaml."""
    root = tmp_path / "ws"
    shutil.copytree(viewer_ws_template, root)
    return root


@pytest.fixture(scope="module")
def browser():
    with chromium(size=(900, 640), webgl=True) as driver:
        yield driver

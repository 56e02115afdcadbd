"""Shared fixtures. ``tests/`` is on ``sys.path`` (pytest's rootdir conftest), so test modules import the
scaffolding in ``tests/fixtures/`` as ``fixtures``."""

from __future__ import annotations

from pathlib import Path

import pytest

from fixtures import FOX, SAMPLE, sample_present


@pytest.fixture(autouse=True)
def _builtins_print_kept():
    """Every test leaves ``builtins.print`` as it found it: ``ray.shutdown()`` leaves Ray's own print behind, and numba
    code compiled later in the same process (Genesis' renderer, on a fresh venv's first render) then fails with
    "Untyped global name 'print'"."""
    import builtins

    before = builtins.print
    yield
    builtins.print = before


@pytest.fixture(scope="session")
def sample_dir() -> Path:
    """The bundled sample capture (samples/tabletop); the test is skipped when it is not in this checkout."""
    if not sample_present():
        pytest.skip(f"the bundled sample is not at {SAMPLE}")
    return SAMPLE


@pytest.fixture(scope="session")
def fox_dir() -> Path:
    """The real fox phone capture (../shared/data/fox); skipped where it is absent."""
    if not (FOX / "transforms.json").is_file():
        pytest.skip(f"real data not present: {FOX} (the fox capture lives in ../shared/data)")
    return FOX


@pytest.fixture(scope="session")
def turned_panda():
    """(spec, links): the Franka Panda's link surfaces at home turned 0.35 rad about its base (the robot samples'
    capture pose), shared by the robot-view and robot-Gaussian tests (MuJoCo FK, ~0.5 s)."""
    import numpy as np

    from mirage2matter.robots import get_robot
    from mirage2matter.robots.surface import robot_surface

    spec = get_robot("panda")
    q = np.asarray(spec.home, float)
    q[0] -= 0.35
    return spec, robot_surface(spec, q)


@pytest.fixture(scope="session")
def sample_world_ws(tmp_path_factory, sample_dir):
    """``make(**sample_world options) -> workspace`` whose ``world/`` is the sample's ground truth (assets in
    ``world/assets``), built once per set of options in this session (CoACD takes a few seconds)."""
    from mirage2matter.world import sample_world

    built: dict[tuple, Path] = {}

    def make(**options) -> Path:
        key = tuple(sorted(options.items()))
        if key not in built:
            ws = tmp_path_factory.mktemp("sample_world")
            sample_world(sample_dir, ws / "world", **options)
            built[key] = ws
        return built[key]

    return make

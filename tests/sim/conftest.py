"""The sample world (ground-truth meshes) for the simulator tests, built once per session."""

from pathlib import Path

import pytest


@pytest.fixture(scope="session")
def sim_ws(sample_world_ws) -> Path:
    return sample_world_ws(gaussians_per_object=3000, scene_density_per_m2=4000.0)

"""A world from the bundled sample's ground truth, built once per test session (CoACD takes a few seconds)."""

from pathlib import Path

import pytest


@pytest.fixture(scope="session")
def sample_ws(sample_world_ws) -> Path:
    return sample_world_ws(gaussians_per_object=4000, scene_density_per_m2=8000.0, max_collision_parts=4)

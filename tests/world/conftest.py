"""A world from the bundled sample's ground truth, built once per test session (CoACD takes a few seconds)."""

from pathlib import Path

import pytest

SAMPLE = Path(__file__).resolve().parents[2] / "samples" / "tabletop"


@pytest.fixture(scope="session")
def sample_ws(tmp_path_factory) -> Path:
    from mirage2matter.world import sample_world

    if not (SAMPLE / "ground_truth.json").is_file():
        pytest.skip(f"bundled sample missing at {SAMPLE}")
    ws = tmp_path_factory.mktemp("world_ws")
    sample_world(SAMPLE, ws, gaussians_per_object=4000, scene_density_per_m2=8000.0, max_collision_parts=4)
    return ws

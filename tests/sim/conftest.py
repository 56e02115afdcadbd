"""The sample world (ground-truth meshes) for the simulator tests, built once per session."""

from pathlib import Path

import pytest

SAMPLE = Path(__file__).resolve().parents[2] / "samples" / "tabletop"


@pytest.fixture(scope="session")
def sim_ws(tmp_path_factory) -> Path:
    from mirage2matter.world import sample_world

    if not (SAMPLE / "ground_truth.json").is_file():
        pytest.skip(f"bundled sample missing at {SAMPLE}")
    ws = tmp_path_factory.mktemp("sim_ws")
    sample_world(SAMPLE, ws, gaussians_per_object=3000, scene_density_per_m2=4000.0)
    return ws

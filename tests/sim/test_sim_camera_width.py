"""Simulator cameras of any even width: Genesis reads its framebuffer in rows of whole 4-byte words, and a frame
98 px wide aborted the process in malloc; such a camera renders 2 px wider and is cropped about its centre."""

from __future__ import annotations

import numpy as np
import pytest

from mirage2matter.env import EnvError
from mirage2matter.world import load_world


def test_a_frame_98_px_wide_is_the_centre_of_one_100_px_wide(sample_world_ws):
    from mirage2matter.env.twin_env import TwinEnv

    world = load_world(sample_world_ws(gaussians_per_object=3000, scene_density_per_m2=4000.0) / "world")

    def first_frame(size):  # the Genesis robot over the splats (the sample world has no robot Gaussians)
        env = TwinEnv(world, "grasp banana", size=size, cameras=("head",))
        try:
            return env.reset(seed=5)[0]["observation.images.head"]
        finally:
            env.close()

    narrow, wide = first_frame((98, 72)), first_frame((100, 72))
    assert narrow.shape == (72, 98, 3)
    np.testing.assert_array_equal(narrow, wide[:, 1:99])
    with pytest.raises(EnvError, match="frames 97 px wide: the simulator's cameras need an even width"):
        first_frame((97, 72))  # before anything is built

"""The per-episode table look (env/table_texture.py): which Gaussians are the table, and what a look does to them."""

from __future__ import annotations

import numpy as np
import pytest

from mirage2matter.render.table_texture import TableTexture, table_rows


def test_table_rows_are_coloured_gaussians_on_the_table_plane_near_the_robot():
    means = np.array([[0.5, 0.0, 0.001], [0.5, 0.0, 0.001], [0.5, 0.0, -0.75], [3.0, 0.0, 0.0], [0.4, 0.1, 0.3]])
    rgb = np.array([[0.6, 0.4, 0.25], [0.9, 0.9, 0.9], [0.6, 0.4, 0.25], [0.6, 0.4, 0.25], [0.6, 0.4, 0.25]])
    # wood on the table | the white board | the floor below | far outside | above the table (an object, the robot)
    assert table_rows(means, rgb, table_z=0.0).tolist() == [True, False, False, False, False]


def test_a_look_is_its_seed_and_changes_colour_and_grain_within_its_strength():
    a = TableTexture.sample(np.random.default_rng(3), 0.3)
    assert a == TableTexture.sample(np.random.default_rng(3), 0.3)
    assert a != TableTexture.sample(np.random.default_rng(4), 0.3)
    assert all(0.7 <= g <= 1.3 for g in a.gain) and 0.0 <= a.amplitude <= 0.3 and 0.0 <= a.flatten <= 0.6
    rng = np.random.default_rng(0)
    xy = rng.uniform(-1.0, 1.0, (20000, 2))
    field = a.grain(xy)
    assert abs(field.mean()) < 0.1 and field.std() == pytest.approx(1.0, abs=0.15)  # zero-mean, unit-variance
    rgb = np.full((len(xy), 3), 0.4)
    out = a.apply(rgb, xy)
    assert out.dtype == np.float32 and out.shape == rgb.shape and (out >= 0).all() and (out <= 1).all()
    # a flat colour: its mean goes by the gain, its spread by the grain
    np.testing.assert_allclose(out.mean(axis=0), 0.4 * np.asarray(a.gain), rtol=0.05)
    assert out[:, 0].std() == pytest.approx(0.4 * a.gain[0] * a.amplitude * field.std(), rel=0.05)


def test_flatten_evens_out_the_reconstructions_own_grain():
    rng = np.random.default_rng(1)
    rgb = rng.uniform(0.2, 0.6, (1000, 3))
    look = TableTexture(flatten=1.0, gain=(1.0, 1.0, 1.0), amplitude=0.0, waves=((1.0, 0.0),), phases=(0.0,))
    out = look.apply(rgb, rng.uniform(size=(1000, 2)))
    np.testing.assert_allclose(out, np.broadcast_to(rgb.mean(axis=0), rgb.shape), atol=1e-6)
    assert set(look.to_json()) == {"flatten", "gain", "amplitude", "waves", "phases"}

"""Fixtures of the policy tests: tiny datasets and one tiny trained policy shared by the session."""

from __future__ import annotations

import pytest

from fixtures.policy_datasets import build_dataset, spec_for, tiny_config
from mirage2matter.policy import train_policy


@pytest.fixture
def make_dataset(tmp_path):
    def make(name: str = "ds", **kw):
        spec = kw.pop("spec", None) or spec_for()
        out = tmp_path / name
        return out, build_dataset(out, spec, **kw)

    return make


@pytest.fixture(scope="session")
def tiny_run(tmp_path_factory):
    """A policy trained to overfit two short episodes (shared by the inference tests): (dataset, out_dir,
    episodes, summary)."""
    root = tmp_path_factory.mktemp("policy_tiny")
    eps = build_dataset(root / "ds", spec_for(), seeds=(0, 1), length=12)
    summary = train_policy(root / "ds", root / "run", tiny_config(), log=lambda s: None, progress=False)
    return root / "ds", root / "run", eps, summary

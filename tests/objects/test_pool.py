"""How many objects the objects stage reconstructs at once (``objects.workers``)."""

from __future__ import annotations

import os

import pytest

from mirage2matter.objects import ObjectsError, pool
from mirage2matter.objects.pool import object_workers


def test_workers_asked_for_are_capped_by_the_objects() -> None:
    assert object_workers(1, 3) == 1
    assert object_workers(5, 3) == 3
    assert object_workers(2, 0) == 1  # nothing to do is still one (in-process) worker


def test_default_is_one_per_object_at_most_two_per_core_and_one_per_2_gib(monkeypatch) -> None:
    monkeypatch.setattr(os, "cpu_count", lambda: 2)
    monkeypatch.setattr(pool, "_available_bytes", lambda: 64 << 30)
    assert object_workers(0, 3) == 3 and object_workers(0, 10) == 4
    monkeypatch.setattr(pool, "_available_bytes", lambda: 5 << 30)  # room for two
    assert object_workers(0, 3) == 2
    monkeypatch.setattr(pool, "_available_bytes", lambda: 1 << 30)
    assert object_workers(0, 3) == 1


def test_negative_workers_is_a_clear_error() -> None:
    with pytest.raises(ObjectsError, match="objects.workers must be >= 0"):
        object_workers(-1, 3)

"""Demonstration datasets: LeRobot v3.0 / v2.1 writers, crash-safe staging, and a validator."""

from .lerobot import FORMATS, write_dataset
from .spec import DatasetSpec, EpisodeData, VideoOptions, video_key
from .staged import StagedEpisode
from .staging import Staging, StagingError, commit_attempt, consolidate, staging_dir_for
from .validate import validate

__all__ = [
    "FORMATS",
    "DatasetSpec",
    "EpisodeData",
    "StagedEpisode",
    "Staging",
    "StagingError",
    "VideoOptions",
    "commit_attempt",
    "consolidate",
    "staging_dir_for",
    "validate",
    "video_key",
    "write_dataset",
]

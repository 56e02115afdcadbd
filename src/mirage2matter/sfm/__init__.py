"""SfM stage: pycolmap reconstruction of the keyframes, and pose comparison against a reference."""

from .colmap import SfMConfig, SfMError, SfMResult, compare_poses, load_model_points, load_sfm_summary, run_sfm

__all__ = ["SfMConfig", "SfMError", "SfMResult", "compare_poses", "load_model_points", "load_sfm_summary", "run_sfm"]

"""Capture stage: keyframes from a hand-held video or an image folder."""

from .keyframes import CaptureConfig, CaptureError, extract_keyframes, load_keyframes, sharpness

__all__ = ["CaptureConfig", "CaptureError", "extract_keyframes", "load_keyframes", "sharpness"]

"""Geometry: similarity transforms, rotations, Umeyama, SH rotation, cameras. Imports nothing of ours."""

"""Calibration: ChArUco boards, metric alignment of SfM to the robot base, hand-eye calibration."""

"""Calibration: camera intrinsics (ChArUco), laser planes (baseline b, angle alpha per line)."""

"""Rigid-body geometry (SE(3)) and the rectified stereo camera model."""

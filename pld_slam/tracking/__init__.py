"""Tracking: the reference frame and the local map, mismatch filters, dynamic features, pose.

The matching itself (frame to frame, map landmarks by projection, without a prior) is
`pld_slam.matching`'s.
"""

"""Tracking: frame-to-frame matching, mismatch filters, dynamic features, pose."""

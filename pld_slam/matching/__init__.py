"""Matching: every descriptor and projection search of the stages above the front end.

One layer that tracking, local mapping, loop closing and the stereo calibration call, as
ORB-SLAM2's ``ORBmatcher`` is; none of those stages imports another for its matching. The
binary descriptors' distances and best-match selection stay in the front end
(`pld_slam.frontend.descriptors`), which its stereo matching needs and which sits below.

`frames`: frame-to-frame matching guided by a predicted motion. `projection`: map
landmarks searched by projection into frames. `fusion`: landmarks projected into
keyframes and fused with what they match there (local mapping's neighbour search, the
two ends of a loop). `prior_free`: matching without a pose prior, and the PnP pose from
it. `windows`: the window search every matcher runs. `observations`: matched features as
pose-only observations.
"""

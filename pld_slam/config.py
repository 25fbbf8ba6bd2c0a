"""Every parameter of pld-slam, as typed dataclasses with the paper's values as defaults.

A configuration is built from the defaults, then YAML files (``configs/*.yaml``) laid
over them in order, then ``section.key=value`` overrides. Each layer is validated as it
is applied: an unknown section or key, a value of the wrong type, a number that is not
finite (``.nan``, ``.inf``), or a value outside its range is a `ConfigError` that names
the file (or override) and the key.

YAML layout: one mapping per section, e.g.::

    filters:
      point_grid_alpha: 1.5
    loop:
      detector: ggs
"""

import dataclasses
import math
import typing
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import yaml

from pld_slam.errors import ConfigError, read_user_text

INT_MAX = 2**31 - 1
"""The largest value of an integer field without an upper bound of its own: OpenCV, numba kernels and index
arrays take them as 32-bit integers, which a larger value overflows."""


def _param(default: Any, doc: str, low: float | None = None, high: float | None = None) -> Any:
    """A config field with its documentation and an optional closed range [low, high] (an integer's ``high`` is
    `INT_MAX` unless given; a number must be finite whatever its range)."""
    return field(default=default, metadata={"doc": doc, "low": low, "high": high})


@dataclass(frozen=True)
class SystemConfig:
    """Run-wide settings."""

    seed: int = _param(0, "seed of every random choice (RANSAC, k-means): same seed, same output", 0)
    prefetch: bool = _param(
        True, "read and extract the next frames in the background while this one is tracked and mapped "
        "(same output, less wall time)"
    )
    prefetch_worker: Literal["process", "thread"] = _param(
        "process", "where prefetch extracts: a forked child process (Linux, where forking is safe; else a thread) "
        "or a thread"
    )
    prefetch_frames: int = _param(
        3, "prefetch reads and extracts this many frames ahead of the one tracked (same output; fewer leave the "
        "worker idle through a keyframe, each costs memory: about 1 MB on KITTI)", 1, 64
    )


@dataclass(frozen=True)
class DatasetConfig:
    """How frames are delivered from the sequence (`pld_slam.datasets.with_cameras`,
    `pld_slam.datasets.StereoSequence.scaled`)."""

    cameras: Literal["auto", "grey", "colour"] = _param(
        "auto", "KITTI's stereo pair: grey (image_0/1, image_00/01), colour (image_2/3, image_02/03, read as grey) "
        "or auto (grey where the folder has it, else colour)"
    )
    scale: float = _param(
        1.0, "resize factor of every frame and of the camera intrinsics (baseline kept); 0.5 halves each side",
        0.05, 1.0,
    )


@dataclass(frozen=True)
class CalibrationConfig:
    """Self-calibration of the stereo rig from the sequence's images (`pld_slam.stereo_calibration`)."""

    disparity_offset: bool = _param(
        True, "estimate the rig's disparity offset (cx_left - cx_right error) from frame pairs before the run"
    )
    anchors: int = _param(12, "places spread over the sequence whose three frames give frame pairs", 1)
    min_anchors: int = _param(
        6, "fewest anchors with a pair pose for an estimate (an anchor takes 2 * gap + 1 frames of its own)", 2
    )
    pair_motion_baselines: float = _param(
        5.0, "an anchor's frames are this far apart [stereo baselines of camera motion]: sets the frame gap", 0.0
    )
    min_frame_gap: int = _param(
        2, "smallest frame gap between an anchor's frames (consecutive frames share their points' sub-pixel errors)", 1
    )
    max_frame_gap: int = _param(5, "largest frame gap between an anchor's frames (pairs must still match)", 1)
    max_offset_px: float = _param(1.0, "the offset is searched in [-this, +this] [px]", 0.1)
    max_sigma_px: float = _param(
        0.1, "the estimate is used only when its standard deviation is under this [px]", 0.0
    )
    min_significance: float = _param(
        2.5, "... and it lies at least this many standard deviations from zero (a smaller one may be noise)", 0.0
    )
    prior_sigma_px: float = _param(
        0.0,
        "a used estimate is shrunk to its posterior mean for rig offsets spread this much about 0 [px] (0: not)",
        0.0,
    )
    gating_rounds: int = _param(
        4, "most rounds of choosing the pairs' inliers at the current offset and stepping to the profile's minimum",
        1, 100
    )
    gating_tolerance_px: float = _param(
        0.005, "a round that moves the offset by less than this [px] is the last", 0.0, 1.0
    )
    pair_pose_rounds: int = _param(
        2, "pose-only solves of a frame pair's pose from its PnP pose, each on the last one's inliers (tracking: 4)",
        1, 20
    )
    pair_pose_robust_rounds: int = _param(
        1, "... of which the first this many use the Huber loss (tracking: 3)", 0, 20
    )


@dataclass(frozen=True)
class PointsConfig:
    """ORB point features: detection, bucketing over the image, stereo matching."""

    n_features: int = _param(1500, "ORB keypoints per image before stereo matching", 1, 100_000)
    scale_factor: float = _param(1.2, "ORB pyramid scale between levels (ORB-SLAM2: 1.2)", 1.01, 2.0)
    n_levels: int = _param(8, "ORB pyramid levels (ORB-SLAM2: 8)", 1, 16)
    fast_threshold: int = _param(20, "FAST corner threshold [grey levels] (ORB-SLAM2: 20)", 1, 255)
    oversampling: float = _param(
        3.0, "ORB detects oversampling * n_features corners; bucketing keeps n_features", 1.0, 20.0
    )
    bucket_size: int = _param(32, "side of the square bucketing cells [px]", 4)
    min_separation_px: int = _param(
        3, "one keypoint per cell of this side [px]: the same corner found at several octaves counts once", 1
    )
    stereo_row_tolerance: float = _param(
        2.0, "stereo candidates lie within this many rows, times scale_factor^octave [px]", 0.0
    )
    stereo_max_distance: int = _param(64, "largest Hamming distance of a stereo match [bits]", 0, 256)
    stereo_ratio: float = _param(
        0.8, "ratio test: best distance < ratio * best rival elsewhere on the row", 0.0, 1.0
    )
    sad_half_window: int = _param(5, "half side of the SAD window of sub-pixel refinement [px at the octave]", 1)
    sad_search_radius: int = _param(5, "SAD search +- this many columns around the match [px at the octave]", 1)
    min_depth_baselines: float = _param(3.0, "nearest stereo point, in baselines (disparity <= fx / this)", 0.01)
    max_depth_baselines: float = _param(
        200.0, "farthest stereo point, in baselines (disparity >= fx / this)", 0.01
    )
    disparity_sigma_px: float = _param(
        0.15, "standard deviation of a stereo disparity at ORB octave 0 [px], in pose and BA costs", 0.001
    )


@dataclass(frozen=True)
class LinesConfig:
    """Line segments (detection, LBD, stereo matching) and the two line error terms of pose estimation."""

    enabled: bool = _param(True, "use line segments at all (off: a point-only system)")
    vertical_error: bool = _param(True, "line vertical error: endpoint distance to the detected line")
    horizontal_error: bool = _param(True, "line horizontal error: endpoint error along the line")
    detector: Literal["lsd", "fld", "edlines"] = _param(
        "lsd", "segment detector: OpenCV's LSD (the paper's), or the faster FastLineDetector or EDLines "
        "(EdgeDrawing), their segments moved onto sub-pixel edges"
    )
    detection_scale: float = _param(
        0.5, "every detector works on the image scaled by this (LSD's own default: 0.8)", 0.1, 1.0
    )
    min_length: float = _param(0.015, "shortest segment kept, as a fraction of the image diagonal", 0.0, 1.0)
    max_lines: int = _param(150, "segments kept per image, longest first", 1)
    min_angle_from_horizontal: float = _param(
        0.26, "segments closer to horizontal than this [rad] have no stable disparity (0.26 = 15 deg)", 0.01, 1.571
    )
    stereo_max_angle_difference: float = _param(
        0.1, "largest direction difference of a stereo line match [rad]", 0.0, 3.142
    )
    stereo_min_row_overlap: float = _param(
        0.5, "shared row range of a stereo line match, as a fraction of the shorter one", 0.0, 1.0
    )
    stereo_max_distance: int = _param(64, "largest LBD Hamming distance of a stereo line match [bits]", 0, 256)
    stereo_ratio: float = _param(
        0.8, "ratio test: best distance < ratio * best rival elsewhere on the row", 0.0, 1.0
    )
    min_depth_baselines: float = _param(3.0, "nearest line endpoint, in baselines (disparity <= fx / this)", 0.01)
    max_depth_baselines: float = _param(
        200.0, "farthest line endpoint, in baselines (disparity >= fx / this)", 0.01
    )
    edge_search_px: int = _param(
        3, "fld, edlines: a kept segment is moved onto the image's edge found up to this far on either side of it "
        "[px] (LSD's segments are sub-pixel already)", 1, 20
    )
    edge_sample_spacing_px: float = _param(
        3.0, "fld, edlines: the edge is sampled every this many pixels along the segment ...", 0.5, 100.0
    )
    edge_min_samples: int = _param(
        6, "... at least this many times (a segment with fewer than half of them usable stays as detected) ...",
        2, 1000
    )
    edge_max_samples: int = _param(32, "... and at most this many times", 2, 10_000)
    edge_min_gradient: float = _param(
        4.0, "fld, edlines: an edge sample counts only where the grey-level gradient across the segment exceeds this "
        "[levels / px]", 0.0, 255.0
    )
    edge_outlier_px: float = _param(
        1.0, "fld, edlines: edge samples farther than this from the segment's median offset are left out of the fit "
        "[px]", 0.0, 20.0
    )


@dataclass(frozen=True)
class FiltersConfig:
    """The two frame-to-frame mismatch filters (paper, sections Track_a and Track_b)."""

    point_grid: bool = _param(True, "point mismatch filter by grid_cval")
    point_grid_cell_width: int = _param(64, "cell width of the point filter's grid [px] (paper: 64 x 48)", 1)
    point_grid_cell_height: int = _param(48, "cell height of the point filter's grid [px] (paper: 64 x 48)", 1)
    point_grid_alpha: float = _param(
        1.5, "a match is an outlier when |g_l - g_r| > alpha times the cell mean (paper: 1.5)", 0.0
    )
    line_llg: bool = _param(True, "line mismatch filter by local line groups (LLG)")
    line_llg_factor: float = _param(
        2.0, "a match is an outlier when its angle or midpoint shift exceeds this times the LLG mean (paper: 2)", 0.0
    )
    point_grid_min_deviation_px: float = _param(
        3.0, "a point match whose grid_cval deviation is below this [px] is never an outlier (noise never rejects)",
        0.0, 1000.0
    )
    point_grid_min_cell_matches: int = _param(
        3, "cells of the point filter with fewer matches than this are not judged: all their matches are kept",
        1, 10_000
    )
    line_llg_min_angle_change_deg: float = _param(
        5.0, "a line match whose direction changes less than this [deg] is never an outlier by angle", 0.0, 90.0
    )
    line_llg_min_midpoint_shift_px: float = _param(
        20.0, "a line match whose midpoint moves less than this [px] is never an outlier by shift (LSD's endpoints "
        "slide along the line)", 0.0, 10_000.0
    )


@dataclass(frozen=True)
class TrackingConfig:
    """Frame-to-frame matching and pose-only estimation (paper, sections Track and Track_d)."""

    point_search_radius_px: float = _param(
        15.0, "window around a point's motion-model prediction searched for its match [px at octave 0]", 1.0
    )
    line_search_radius_px: float = _param(
        30.0, "window around a line midpoint's motion-model prediction searched for its match [px]", 1.0
    )
    line_max_angle_change: float = _param(
        0.2, "largest direction change of a frame-to-frame line match from its prediction [rad]", 0.0, 3.142
    )
    wide_search_factor: float = _param(
        4.0, "search windows grow by this factor when the first search finds too few matches", 1.0
    )
    max_point_distance: int = _param(64, "largest ORB Hamming distance of a frame-to-frame match [bits]", 0, 256)
    max_line_distance: int = _param(64, "largest LBD Hamming distance of a frame-to-frame match [bits]", 0, 256)
    ratio: float = _param(0.9, "ratio test of frame-to-frame matches: best < ratio * best rival", 0.0, 1.0)
    line_sigma_px: float = _param(1.0, "standard deviation of a line endpoint's image position [px]", 0.01)
    border_margin_px: float = _param(
        10.0, "a line's horizontal error is used only when both endpoints are this far inside the image", 0.0
    )
    min_inliers: int = _param(
        20, "fewer inlier points + lines than this is a tracking failure: the motion model is kept", 1
    )
    reference_max_age: int = _param(
        5, "frames tracked against one reference frame before the current frame becomes the reference", 1
    )
    reference_min_inlier_ratio: float = _param(
        0.5, "the current frame becomes the reference when inliers fall below this share of the first", 0.0, 1.0
    )
    relocalisation_keyframes: int = _param(
        5, "keyframes most similar by GGS tried, in order, when the local map cannot pose a frame", 0
    )
    prior_free_ratio: float = _param(
        0.8, "ratio test of descriptor matches without a pose prior (relocalisation, loop check, stereo calibration): "
        "best < ratio * second best (ORB-SLAM2's relocalisation: 0.75-0.8)", 0.0, 1.0
    )
    pnp_min_inliers: int = _param(
        30, "fewest PnP inliers (and descriptor matches to try PnP on) of a pose without a prior (relocalisation, "
        "stereo calibration; the loop check asks loop.min_inliers matches)", 4, 10_000
    )
    pnp_iterations: int = _param(300, "RANSAC iterations of the PnP pose without a prior", 1, 100_000)
    pnp_confidence: float = _param(
        0.999, "RANSAC of the PnP pose stops early once a pose is right with this probability", 0.01, 0.999999
    )
    pnp_reprojection_px: float = _param(
        3.0, "a PnP RANSAC inlier reprojects within this many pixels [px at octave 0]", 0.1, 100.0
    )
    pose_rounds: int = _param(
        4, "solves of a frame's pose-only estimate, each on the inliers of the last (ORB-SLAM2: 4)", 1, 20
    )
    pose_robust_rounds: int = _param(
        3, "... of which the first this many use the Huber loss (ORB-SLAM2: 3)", 0, 20
    )
    pose_max_nfev: int = _param(100, "residual evaluations allowed per pose-only solve", 1, 10_000)
    pose_cost_tolerance: float = _param(
        1e-5, "a pose-only solve stops when a step lowers the cost by less than this share of it (least_squares' "
        "ftol)", 1e-12, 0.5
    )


@dataclass(frozen=True)
class DynamicConfig:
    """Dynamic feature detection (paper, section Track_c; ablation switches)."""

    grid: bool = _param(True, "dynamic grid: drop points in cells that disagree with the motion model")
    llg: bool = _param(True, "dynamic LLG: drop lines in groups that disagree with the motion model")
    error_ratio: float = _param(
        4.0, "a cell (mean offset) / LLG (median distance) is dynamic over this times the frame's median error", 1.0
    )
    min_point_error: float = _param(
        2.5, "... and over this many sigmas for points (noise never counts as motion)", 0.0
    )
    min_line_error_px: float = _param(3.0, "... and over this many pixels for lines", 0.0)
    disparity_sigma_px: float = _param(
        0.5, "standard deviation of a stereo disparity at ORB octave 0 [px]: the depth uncertainty of a point", 0.0
    )
    min_cell_matches: int = _param(2, "matches a grid cell needs to be judged", 1)
    member_ratio: float = _param(
        0.7, "a line of a dynamic LLG, or a feature dynamic before, is dynamic when its error exceeds this times the "
        "threshold", 0.0
    )
    rival_min_share: float = _param(
        0.15, "a robust solve that rejects this share of the matches is checked for the static world's motion, "
        "and a coherent motion needs this share as inliers to be a candidate (pld_slam.localisation.static_world)",
        0.0, 1.0
    )
    motion_prior_m: float = _param(
        0.05, "expected error of the constant-velocity prediction per frame [m]: a motion within it agrees with the "
        "motion model", 0.0
    )
    motion_prior_deg: float = _param(0.5, "... and [deg]", 0.0)
    from_masks: bool = _param(
        False, "take the labels from the sequence's dynamic_masks/ instead of the two detectors (ground truth or a "
        "segmentation: the best any detector could do)"
    )
    mask_margin_px: int = _param(
        2, "a feature within this many pixels of the moving-object mask lies on it (from_masks' labels and the run "
        "summary's mask scores: a corner on an object's outline moves with it)", 0, 100
    )
    static_world_hypotheses: int = _param(
        200, "RANSAC hypotheses (triples of stereo matches) per coherent motion of the static-world check "
        "(pld_slam.localisation.static_world)", 1, 100_000
    )


@dataclass(frozen=True)
class GgsConfig:
    """Global gray similarity descriptor of the left image (paper, section Track_e)."""

    scale: float = _param(0.8, "scale of the second, shrunk copy of the image (paper: 0.8)", 0.05, 1.0)
    grid_rows: int = _param(3, "grid rows per image (paper: 3 x 4)", 1)
    grid_cols: int = _param(4, "grid columns per image (paper: 3 x 4)", 1)
    bins: int = _param(256, "grey-level histogram bins per cell (paper: 256)", 2, 256)
    place_ranks: bool = _param(
        True, "place recognition (loop detection, relocalisation) compares the grey histograms and as many "
        "of the grey levels' ranks, which a change of exposure does not move; the keyframe rule compares "
        "grey histograms only (not in the paper; pld_slam.frontend.ggs)"
    )


@dataclass(frozen=True)
class KeyframesConfig:
    """Keyframe selection: the paper's GGS rule or ORB-SLAM2's, and safety rules (`pld_slam.keyframes`)."""

    policy: Literal["ggs", "tracked_ratio"] = _param(
        "ggs", "which rule inserts keyframes: GGS threshold (paper) or tracked-landmark ratio (ORB-SLAM2)"
    )
    ggs_gain: float = _param(
        0.4, "GGS_th = GGS_pKF + gain * (GGS_pKF+1 - GGS_ppKF+1) (paper: 0.4)", 0.0
    )
    ggs_initial_steps: float = _param(
        2.0, "the first GGS_th, in GGS changes of one frame after the first keyframe (the paper leaves the start "
        "open)", 0.0
    )
    tracked_ratio: float = _param(
        0.9, "tracked_ratio policy: a keyframe when the frame tracks fewer than this share of its reference "
        "keyframe's landmarks (ORB-SLAM2: 0.9)", 0.0, 1.0
    )
    min_tracked_ratio: float = _param(
        0.5, "safety, both policies: a keyframe when the frame tracks fewer than this share of its reference "
        "keyframe's landmarks (ORB-SLAM2: 0.25 emergency, 0.75 main)", 0.0, 1.0
    )
    max_frames_between: int = _param(
        10, "safety, both policies: a keyframe at the latest after this many frames (ORB-SLAM2: one second)", 1
    )


@dataclass(frozen=True)
class MappingConfig:
    """Local map, covisibility graph and local BA (paper, sections LM and Local BA; `pld_slam.mapping`)."""

    enabled: bool = _param(True, "build a map and track it (off: visual odometry against a reference frame)")
    covisibility_min_shared: int = _param(
        20, "landmarks two keyframes must share for a covisibility edge (paper: 20)", 1
    )
    local_ba_window: int = _param(
        10, "covisible keyframes optimised by local BA with each new keyframe (their landmarks too)", 1
    )
    local_ba_min_frames: int = _param(
        2, "local BA runs at a keyframe this many frames or more after the last local BA's keyframe "
        "(1: at every keyframe)", 1
    )
    local_ba_max_nfev: int = _param(
        10, "residual evaluations of each of the two local BA solves (robust, then without outliers)", 1
    )
    ba_cost_tolerance: float = _param(
        1e-3, "local and global BA stop when a step lowers the cost by less than this share of it (least_squares' "
        "ftol): they refine a map tracking put near its optimum", 1e-12, 0.5
    )
    ba_lsmr_iterations: int = _param(
        10, "LSMR iterations of each step of local and global BA (an inexact Gauss-Newton step the trust region "
        "accepts or shrinks)", 1, 10_000
    )
    fusion_second_neighbours: int = _param(
        5, "a new keyframe's landmarks are fused into its local_ba_window strongest covisible keyframes and this many "
        "strongest covisible keyframes of each (ORB-SLAM2: 5)", 0, 1000
    )
    tracking_keyframes: int = _param(
        20, "keyframes whose landmarks form the local map tracked by each frame", 1
    )
    point_search_radius_px: float = _param(
        4.0, "window around a map point's projection searched for its match [px at its predicted octave 0]", 0.5
    )
    line_search_radius_px: float = _param(
        15.0, "window around a map line midpoint's projection searched for its match [px]", 0.5
    )
    max_point_distance: int = _param(
        100, "largest ORB Hamming distance of a map point's match when tracking the local map [bits] (ORB-SLAM2: 100)",
        0, 256
    )
    ratio: float = _param(
        0.8, "ratio test of a map point's match when tracking the local map: best < ratio * best rival "
        "(ORB-SLAM2: 0.8)",
        0.0, 1.0
    )
    search_nearest_scale: float = _param(
        0.8, "a map point is searched no nearer than this times the nearest distance its ORB scale invariance "
        "allows ... (ORB-SLAM2: 0.8)", 0.01, 1.0
    )
    search_farthest_scale: float = _param(
        1.2, "... and no farther than this times the farthest (ORB-SLAM2: 1.2)", 1.0, 100.0
    )
    max_viewing_angle: float = _param(
        1.047, "a landmark seen more than this angle [rad] away from its mean viewing direction is not searched "
        "(ORB-SLAM2: 60 deg)", 0.0, 3.142
    )
    min_observation_weight: int = _param(
        4, "a landmark is culled when, min_observation_age keyframes after its creation, its observations weigh less "
        "than this (a stereo observation 2, a left-image-only one 1; ORB-SLAM2 stereo: more than 3)", 1
    )
    min_observation_age: int = _param(
        2, "keyframes after its creation at which a new landmark's observations must weigh min_observation_weight "
        "(ORB-SLAM2: 2)", 0, 1000
    )
    recent_landmark_keyframes: int = _param(
        3, "a new landmark is judged by min_found_ratio and min_observation_weight for this many keyframes after its "
        "creation (ORB-SLAM2: 3)", 1, 1000
    )
    min_found_ratio: float = _param(
        0.25, "a new landmark is culled when matched in fewer than this share of the frames that should see it",
        0.0, 1.0
    )
    redundant_keyframe_ratio: float = _param(
        0.9, "a keyframe is culled when this share of its landmarks is seen by redundant_observers other keyframes",
        0.0, 1.0
    )
    redundant_observers: int = _param(3, "other keyframes that make a landmark of a keyframe redundant", 1)
    dynamic_streak: int = _param(
        2, "a landmark matched to a feature labelled dynamic, lying under one, or seen through, in this many "
        "frames since tracking last found it static is removed", 1
    )
    dynamic_memory: int = _param(
        10, "a landmark found static within this many tracked frames after it was seen moving keeps its dynamic "
        "streak (a slow mover is still found where it was; 0: any find ends the streak)", 0
    )
    max_missed_frames: int = _param(
        10, "a landmark in view (a point in front of the camera, inside the image and not hidden by a nearer mover; "
        "a line predicted in view) that tracking does not find in this many frames, with no find in between, is "
        "removed (0: never)", 0
    )
    see_through: bool = _param(
        True, "a point landmark missed where the stereo pair sees a farther surface, or found by a keypoint without a "
        "stereo match where the pair shows another depth, counts toward its dynamic streak"
    )
    mover_depth_tolerance: float = _param(
        0.2, "a missed point landmark lies under a mover when a stereo point labelled dynamic near its projection "
        "stands within this share of its depth, and is hidden when one stands nearer than that", 0.0, 1.0
    )
    see_through_half_window: int = _param(
        3, "see_through: half side of the window matched along the row [px at full resolution] (2 * this + 1 "
        "square)", 1, 50
    )
    see_through_reach: float = _param(
        3.0, "see_through: disparities are searched from 0 to this times the landmark's predicted disparity", 1.0, 100.0
    )
    see_through_depth_tolerance: float = _param(
        0.1, "see_through: the surface the pair matches must lie farther than the landmark (another depth, for a "
        "found one) by more than this share of its depth ...", 0.0, 10.0
    )
    see_through_margin_px: float = _param(
        1.0, "... and by more than this disparity [px]", 0.0, 100.0
    )
    see_through_match_ratio: float = _param(
        0.5, "... and cost at most this times both the cost at the landmark's own disparity and the window's "
        "contrast", 0.0, 1.0
    )


@dataclass(frozen=True)
class LoopConfig:
    """Loop detection and correction (paper, section LC; `pld_slam.loop`)."""

    detector: Literal["ggs", "bow", "none"] = _param(
        "ggs", "place recognition: GGS (paper), bag of words (rival) or none (no loop closure)"
    )
    vocabulary: str = _param(
        "", "vocabulary file of the bow detector (`pld-slam vocabulary build ... --out vocab.npz`); empty: none"
    )
    bow_consistency: int = _param(
        3, "bow: consecutive keyframes whose candidate groups must overlap (ORB-SLAM2's group consistency)", 0
    )
    bow_covisible_check: bool = _param(
        True, "bow: a candidate not yet consistent in time is verified too, and accepted when the pose found also "
        "holds in bow_consistency of the keyframe's covisible keyframes (ORB-SLAM3)"
    )
    exclude_recent_keyframes: int = _param(
        20, "the keyframes inserted just before a new one are never its loop candidates", 0
    )
    candidates: int = _param(3, "most similar candidates verified per keyframe", 1)
    min_inliers: int = _param(
        60, "point and line inliers the geometric check needs between a keyframe and its loop candidate's map", 1
    )
    max_drift_ratio: float = _param(
        0.03, "a loop may move its keyframe by at most this share of the path since the candidate, plus "
        "drift_allowance_m", 0.0
    )
    drift_allowance_m: float = _param(
        1.0, "... plus this [m], whatever the path (a short path's drift is not a share of it)", 0.0, 1000.0
    )
    max_drift_deg: float = _param(20.0, "a loop may turn its keyframe by at most this [deg]", 0.0, 180.0)
    max_distance_m: float = _param(
        3.0, "a loop joins keyframes whose cameras, as the check places them, are at most this far apart [m]", 0.0
    )
    max_view_angle_deg: float = _param(
        30.0, "... and whose optical axes are at most this far apart [deg]", 0.0, 180.0
    )
    lc_rat_alpha: float = _param(
        0.001, "alpha of lc_rat = ratio_inl * (1 - alpha * ||log(T_i T_j^-1)||), our reading (paper: 0.001)", 0.0
    )
    lc_rat_threshold: float = _param(0.2, "a candidate whose lc_rat lies below this is rejected (paper: 0.2)", 0.0)
    pose_graph_min_shared_ratio: float = _param(
        0.2, "share of common features for a pose-graph edge (paper: 20%)", 0.0, 1.0
    )
    pose_graph_max_nfev: int = _param(30, "residual evaluations of the pose-graph solve", 1)
    bow_common_words_ratio: float = _param(
        0.8, "bow: a candidate shares at least this share of the most words any keyframe shares with the new one "
        "(ORB-SLAM2: 0.8)", 0.0, 1.0
    )
    bow_group_neighbours: int = _param(
        10, "bow: strongest covisible neighbours of a candidate that join its group's accumulated score (ORB-SLAM2: "
        "10)", 0, 1000
    )
    bow_retain_ratio: float = _param(
        0.75, "bow: a group is a candidate when its accumulated score exceeds this share of the best group's "
        "(ORB-SLAM2: 0.75)", 0.0, 1.0
    )
    bow_covisible_inlier_share: float = _param(
        0.5, "bow_covisible_check: a covisible keyframe confirms the loop with at least this share of min_inliers "
        "inliers (ORB-SLAM3: 30 projection matches against 50-80 of the keyframe)", 0.0, 1.0
    )
    bow_covisible_window: int = _param(
        10, "bow_covisible_check: strongest covisible keyframes of the new one in which the loop's pose is tried "
        "(ORB-SLAM3: 10)", 1, 1000
    )


@dataclass(frozen=True)
class OptimizeConfig:
    """The final global bundle adjustment (paper, section LC: "when the system is finished")."""

    global_ba: bool = _param(True, "bundle-adjust every keyframe and landmark at the end of the run")
    global_ba_max_nfev: int = _param(
        20, "residual evaluations of each of the two global BA solves (robust, then without outliers)", 1
    )


@dataclass(frozen=True)
class Config:
    """The whole configuration: one field per YAML section."""

    system: SystemConfig = field(default_factory=SystemConfig)
    dataset: DatasetConfig = field(default_factory=DatasetConfig)
    calibration: CalibrationConfig = field(default_factory=CalibrationConfig)
    points: PointsConfig = field(default_factory=PointsConfig)
    lines: LinesConfig = field(default_factory=LinesConfig)
    filters: FiltersConfig = field(default_factory=FiltersConfig)
    tracking: TrackingConfig = field(default_factory=TrackingConfig)
    dynamic: DynamicConfig = field(default_factory=DynamicConfig)
    ggs: GgsConfig = field(default_factory=GgsConfig)
    keyframes: KeyframesConfig = field(default_factory=KeyframesConfig)
    mapping: MappingConfig = field(default_factory=MappingConfig)
    loop: LoopConfig = field(default_factory=LoopConfig)
    optimize: OptimizeConfig = field(default_factory=OptimizeConfig)


def _check_value(where: str, name: str, kind: Any, spec: dataclasses.Field, value: Any) -> Any:
    """Return ``value`` converted to the field's type ``kind``, or raise `ConfigError`.

    Accepted: bool only for bool (YAML ``true``/``false``); int for int (not bool); int or
    float for float, or text that is a number (PyYAML reads ``1e-6``, without a dot, as
    text); one of the listed strings for a Literal; a string for str.
    """
    got = f"{type(value).__name__} {value!r}"
    if typing.get_origin(kind) is Literal:
        choices = typing.get_args(kind)
        if value not in choices:
            raise ConfigError(f"{where}: {name} must be one of {', '.join(choices)}, got {value!r}")
        return value
    if kind is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where}: {name} must be a string, got {got}")
        return value
    if kind is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: {name} must be true or false, got {got}")
        return value
    high = spec.metadata["high"]
    if kind is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}: {name} must be an integer, got {got}")
        high = INT_MAX if high is None else high
    elif kind is float:
        if isinstance(value, str):
            value = _number_or_text(value)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{where}: {name} must be a number, got {got}")
        if not math.isfinite(value):
            raise ConfigError(f"{where}: {name} must be a finite number, got {got}")
        value = float(value)
    low = spec.metadata["low"]
    if (low is not None and value < low) or (high is not None and value > high):
        bounds = f"[{low if low is not None else '-inf'}, {high if high is not None else 'inf'}]"
        raise ConfigError(f"{where}: {name} = {value!r} is outside {bounds}")
    return value


def _number_or_text(text: str) -> float | str:
    """``text`` as a float where it spells one (``1e-6``), else unchanged."""
    try:
        return float(text)
    except ValueError:
        return text


ORDERED_KEYS = (
    ("calibration.min_anchors", "calibration.anchors"),
    ("calibration.min_frame_gap", "calibration.max_frame_gap"),
    ("points.min_depth_baselines", "points.max_depth_baselines"),
    ("lines.min_depth_baselines", "lines.max_depth_baselines"),
    ("lines.edge_min_samples", "lines.edge_max_samples"),
)
"""Pairs of keys whose first may not exceed the second: in the wrong order each would quietly
switch something off (no disparity-offset estimate ever, no stereo point or line)."""


def check_key_order(config: Config, where: str) -> None:
    """Raise `ConfigError` naming ``where`` when a pair of `ORDERED_KEYS` is out of order."""
    for lower, upper in ORDERED_KEYS:
        low, high = (getattr(getattr(config, key.split(".")[0]), key.split(".")[1]) for key in (lower, upper))
        if low > high:
            raise ConfigError(f"{where}: {lower} = {low!r} exceeds {upper} = {high!r}")


def _section_types() -> dict[str, type]:
    return {f.name: typing.get_type_hints(Config)[f.name] for f in dataclasses.fields(Config)}


def _apply_section(section: Any, section_name: str, values: Any, where: str) -> Any:
    """A copy of one section dataclass with ``values`` (a mapping) applied and validated."""
    if not isinstance(values, Mapping):
        raise ConfigError(f"{where}: section {section_name} must be a mapping of keys to values")
    specs = {spec.name: spec for spec in dataclasses.fields(section)}
    kinds = typing.get_type_hints(type(section))
    changes = {}
    for key, value in values.items():
        name = f"{section_name}.{key}"
        if key not in specs:
            raise ConfigError(
                f"{where}: unknown key {name} (known: {', '.join(sorted(specs))})"
            )
        changes[key] = _check_value(where, name, kinds[key], specs[key], value)
    return dataclasses.replace(section, **changes)


def apply_mapping(config: Config, data: Any, where: str) -> Config:
    """``config`` with a nested mapping ``{section: {key: value}}`` laid over it.

    ``where`` names the source (a file path or ``--set``) in error messages.
    """
    if data is None:
        return config
    if not isinstance(data, Mapping):
        raise ConfigError(f"{where}: expected a mapping of sections, got {type(data).__name__}")
    sections = _section_types()
    changes = {}
    for section_name, values in data.items():
        if section_name not in sections:
            raise ConfigError(
                f"{where}: unknown section {section_name} (known: {', '.join(sections)})"
            )
        current = getattr(config, section_name)
        changes[section_name] = _apply_section(current, section_name, values, where)
    return dataclasses.replace(config, **changes)


def read_yaml(path: Path) -> Any:
    """Parsed content of a YAML file, or `ConfigError` naming the file."""
    return parse_yaml(read_user_text(path, ConfigError, "config"), str(path))


def parse_yaml(text: str, where: str) -> Any:
    """Parsed YAML ``text``, or `ConfigError` naming ``where`` (a file) and the line."""
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as error:
        mark = getattr(error, "problem_mark", None)
        line = f":{mark.line + 1}" if mark is not None else ""
        raise ConfigError(f"{where}{line}: not valid YAML") from error


def parse_override(text: str) -> dict[str, dict[str, Any]]:
    """``"section.key=value"`` as ``{section: {key: value}}``; the value is read as YAML."""
    dotted, sep, raw = text.partition("=")
    section, dot, key = dotted.strip().partition(".")
    if not sep or not dot or not section or not key or "." in key:
        raise ConfigError(f"--set {text}: expected section.key=value")
    try:
        value = yaml.safe_load(raw) if raw.strip() else raw
    except yaml.YAMLError as error:
        raise ConfigError(f"--set {text}: value is not valid YAML") from error
    return {section: {key: value}}


def load_config(paths: Sequence[Path] = (), overrides: Sequence[str] = ()) -> Config:
    """The defaults, then each YAML file in ``paths``, then each ``section.key=value`` override."""
    config = Config()
    for path in paths:
        config = apply_mapping(config, read_yaml(path), str(path))
    for text in overrides:
        config = apply_mapping(config, parse_override(text), f"--set {text}")
    check_key_order(config, ", ".join([*map(str, paths), *(f"--set {text}" for text in overrides)]) or "defaults")
    return config


def config_to_dict(config: Config) -> dict[str, dict[str, Any]]:
    """The configuration as plain nested dicts (for YAML and JSON reports)."""
    return dataclasses.asdict(config)


def dump_config(config: Config) -> str:
    """The configuration as YAML text that `load_config` reads back to the same value."""
    return yaml.safe_dump(config_to_dict(config), sort_keys=False)

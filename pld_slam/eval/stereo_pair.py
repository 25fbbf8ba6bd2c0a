"""Does a run's stereo pair agree with a rectified, synchronised rig? Judged from the front end's counts.

A right camera one frame late (its images shifted by one file) ran to the end without a
complaint on KITTI 06: ATE 1.03 m instead of 0.053, a path of 9.3 m against 13.3. Its
stereo matching still finds points along each row, with depths that do not fit a rigid
rig. Two measures over the whole run, both from what every frame's front end counts
(`pld_slam.frontend.points.stereo_agreement`, about 1.6 ms a KITTI pair):

- the keypoint share: left keypoints with a stereo match, over all left keypoints;
- the row agreement: of the descriptor matches of a quarter of the left keypoints in a
  band four times as high as the stereo search's, those within the stereo row tolerance.
  On a rectified, synchronised pair the matches the wider band adds are rare mistakes;
  when the right image is of another moment, the scene's motion moves its corners off
  the row (away from the focus of expansion) and many best matches with them.

Measured on 12 frames spread over each sequence (counts summed), with the family config:

| sequence | good pair | right 1 frame late | 2 frames late | left/right swapped | right = left |
|---|---|---|---|---|---|
| KITTI odometry 04 | 0.383 / 0.921 | 0.184 / 0.650 | 0.117 / 0.568 | 0.004 / 0.384 | 0.004 / 0.642 |
| KITTI odometry 06 | 0.302 / 0.929 | 0.115 / 0.623 | 0.054 / 0.562 | 0.003 / 0.302 | 0.003 / 0.609 |
| KITTI raw 0005 | 0.233 / 0.917 | 0.093 / 0.744 | 0.037 / 0.540 | 0.003 / 0.250 | 0.003 / 0.706 |
| EuRoC V1_01 flight | 0.543 / 0.960 | 0.383 / 0.738 | 0.261 / 0.618 | 0.002 / 0.049 | 0.008 / 0.021 |
| EuRoC V1_01 static | 0.418 / 0.943 | 0.415 / 0.946 | 0.414 / 0.944 | 0.006 / 0.106 | 0.012 / 0.033 |
| synth static | 0.448 / 0.970 | 0.234 / 0.575 | 0.134 / 0.498 | 0.004 / 0.296 | 0.004 / 0.706 |
| synth static, KITTI camera | 0.426 / 0.947 | 0.206 / 0.494 | 0.124 / 0.421 | 0.006 / 0.183 | 0.011 / 0.560 |
| synth dynamic | 0.383 / 0.963 | 0.182 / 0.519 | 0.094 / 0.470 | 0.003 / 0.323 | 0.004 / 0.682 |
| synth highway | 0.338 / 0.968 | 0.108 / 0.792 | 0.083 / 0.767 | 0.015 / 0.718 | 0.014 / 0.780 |
| synth lowtexture | 0.418 / 0.918 | | | | |

(keypoint share / row agreement; synthetic: 40 frames (low texture: 30), seed 0, 640 x 480 or KITTI's
1241 x 376; a shifted pair's last frames keep the last right image.)
Every good pair has a share of at least 0.23 and an agreement of at least 0.917; every
moving sequence with a late right camera an agreement of at most 0.792, and a swapped or
duplicated pair a share of at most 0.015. A still camera (EuRoC's static extract) with a
late right camera agrees, rightly: its images do not change.

Verdicts: ``agrees``; ``rows_disagree`` (agreement under `MIN_ROW_AGREEMENT`: out of
sync, or not rectified) and ``few_matches`` (share under `MIN_KEYPOINT_SHARE`, the
matches on the row: a scene too poor in texture or too far for depths) are warnings;
``not_a_pair`` (both) is what a swapped pair, the same image twice, two unrelated
cameras or a right camera far out of sync give (two frames late: raw 0005 above, and
KITTI 06 over its whole run, share 0.040 and ATE 9.9 m), and `pld-slam run` ends with
an error once its files are written: no depth of such a run can be right, and its share
is a fifth of the lowest good pair's or less. A late camera stays a warning: its
agreement is only 0.125 below the lowest good pair's, and a slightly misrectified rig
still gives a usable trajectory.
"""

from collections.abc import Sequence

from pld_slam.frontend import StereoAgreement
from pld_slam.system import FrameRecord

MIN_KEYPOINT_SHARE = 0.05
"""Below this share of left keypoints with a stereo match the pair gives no depths to speak of
(good pairs: 0.23 and above; swapped or identical: 0.015 and below)."""

MIN_ROW_AGREEMENT = 0.86
"""Below this share of band matches on the row the pair is out of sync or not rectified
(good pairs: 0.917 and above; a right camera one frame late, moving: 0.792 and below)."""

MIN_BAND_MATCHES = 20
"""Fewer band matches over the run than this say nothing of the row agreement."""


def stereo_pair_summary(records: Sequence[FrameRecord]) -> dict:
    """The summary's ``stereo_pair``: both measures over the frames whose images were read, the
    verdict (module docstring) and, unless the pair agrees, the warning in words (None then).

    ``keypoint_share`` is null without a frame read, ``row_agreement`` with fewer than
    `MIN_BAND_MATCHES` band matches; the verdict is ``unknown`` without a frame read.
    """
    counts = [record.stereo for record in records if record.stereo is not None]
    total = StereoAgreement(*(sum(getattr(c, name) for c in counts) for name in StereoAgreement.__dataclass_fields__))
    share = total.stereo / total.keypoints if total.keypoints else None
    agreement = total.on_row / total.band_matches if total.band_matches >= MIN_BAND_MATCHES else None
    verdict = stereo_pair_verdict(share, agreement)
    return {
        "keypoint_share": share,
        "row_agreement": agreement,
        "frames": len(counts),
        "band_matches": total.band_matches,
        "verdict": verdict,
        "warning": stereo_pair_warning(verdict, share, agreement),
    }


def stereo_pair_verdict(share: float | None, agreement: float | None) -> str:
    """``agrees``, ``rows_disagree``, ``few_matches``, ``not_a_pair`` or ``unknown`` (module docstring)."""
    if share is None:
        return "unknown"
    rows_off = agreement is not None and agreement < MIN_ROW_AGREEMENT
    if share < MIN_KEYPOINT_SHARE:
        return "not_a_pair" if rows_off or agreement is None else "few_matches"
    return "rows_disagree" if rows_off else "agrees"


def stereo_pair_warning(verdict: str, share: float | None, agreement: float | None) -> str | None:
    """What a verdict other than ``agrees`` (or ``unknown``) means for the run, in one line; None for those."""
    measures = (f"{_percent(share)} of the left keypoints have a stereo match (a good pair: 23 % or more), "
                f"{_percent(agreement)} of the left-right matches lie on their row (92 % or more)")
    if verdict == "rows_disagree":
        return (f"the stereo pair disagrees: {measures}; the right images may be out of sync with the left "
                "(shifted by a frame) or not rectified, and the depths and trajectory wrong")
    if verdict == "few_matches":
        return (f"few stereo matches: {measures}; a scene too poor in texture or too far away for depths, "
                "or a pair that does not match")
    if verdict == "not_a_pair":
        return (f"not a stereo pair: {measures}; left and right swapped, the same images twice, images far "
                "out of sync, or of two cameras that are not a rectified pair")
    return None


def _percent(value: float | None) -> str:
    """``value`` as a percentage with one decimal, ``n/a`` for None."""
    return "n/a" if value is None else f"{100.0 * value:.1f} %"

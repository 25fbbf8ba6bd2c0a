"""Did a run track enough of its frames to be of use? The share it tracked, a verdict and the likely cause.

A frame the tracker loses keeps the motion model's guess (or the identity before the first
usable frame), so a run that loses many frames writes a trajectory that looks whole and
is not. Good inputs lose almost none: every real extract and synthetic scenario tracked
all its frames at the default config, the synthetic highway 59 of 60; broken inputs that
still track some frames (the later right images replaced by the left ones, or blank; half
the frames unreadable) tracked 51-80 % (record 0024, which has the table).

The rule (record 0024): the tracked share is over every frame the run processed (an
unreadable frame, and one before the first usable frame, counts as lost); a frame is
tracked unless `TrackingStatus.LOST` (the first frame and a relocalised one count).

- ``none_tracked``: every frame lost (an error, as before);
- ``few_tracked``: a share under `MIN_TRACKED_SHARE` and at least `MIN_LOST_TO_FAIL` frames
  lost (an error: ``pld-slam run`` writes its files, then exits 2);
- ``some_lost``: a share under `WARN_TRACKED_SHARE` short of that (a ``warning:`` line);
- ``tracked``: the rest; ``unknown`` without a frame.

The likely cause comes from the lost frames themselves: mostly unreadable, the image
files; read but with few stereo points against the tracked frames' (under
`FEW_STEREO_POINTS_RATIO` of their median), a right image that does not match the left or
images too dark; with their stereo points, the motion (too fast, frames missing or out of
order) or a view filled by movers.
"""

from collections.abc import Sequence

import numpy as np

from pld_slam.system import FrameRecord
from pld_slam.tracking.tracker import TrackingStatus

MIN_TRACKED_SHARE = 0.9
"""Under this share of its frames tracked a run is an error (good inputs: 0.983 and above; broken
inputs that track some frames: 0.804 and below; record 0024)."""

WARN_TRACKED_SHARE = 0.95
"""Under this share tracked (but not under `MIN_TRACKED_SHARE`) a run is a warning."""

MIN_LOST_TO_FAIL = 2
"""A run with fewer lost frames than this is never an error, however short: a 3-frame run losing one
frame warns, losing both frames after the first fails (record 0024)."""

FEW_STEREO_POINTS_RATIO = 0.25
"""Lost frames whose median stereo points are under this share of the tracked frames' lost their depths
(a right image replaced by the left or blank: 0-6 against about 600; a lost frame of the synthetic
highway: 180 against 232)."""

NOTHING_TRACKED_CAUSES = ("left and right images swapped or the same, images too dark (e.g. 12-bit data in "
                          "16-bit PNGs), or a calibration that does not fit them")
"""The likely causes of a run that tracked none of its frames."""


def tracked_frames_summary(records: Sequence[FrameRecord]) -> dict:
    """The summary's ``tracking``: frames, tracked, lost and their share, the first lost frame, the
    unreadable ones, the median stereo points of the lost frames read and of the tracked ones, the
    verdict (module docstring) and, for any verdict but ``tracked`` and ``unknown``, the message."""
    frames = len(records)
    lost = [record for record in records if record.status is TrackingStatus.LOST]
    tracked = [record for record in records if record.status is not TrackingStatus.LOST]
    unreadable = [record for record in lost if record.stereo is None and record.skipped_reason]
    lost_read = [record for record in lost if record.stereo is not None]
    summary = {
        "frames": frames,
        "tracked": len(tracked),
        "lost": len(lost),
        "tracked_share": len(tracked) / frames if frames else None,
        "first_lost": lost[0].index if lost else None,
        "unreadable": len(unreadable),
        "stereo_points_median": {"tracked": _median([r.n_points for r in tracked]),
                                 "lost": _median([r.n_points for r in lost_read])},
    }
    verdict = tracked_frames_verdict(frames, len(lost))
    return {**summary, "verdict": verdict, "message": _message(verdict, summary, records, unreadable)}


def tracked_frames_verdict(frames: int, lost: int) -> str:
    """``tracked``, ``some_lost``, ``few_tracked``, ``none_tracked`` or ``unknown`` (module docstring)."""
    if frames == 0:
        return "unknown"
    if lost == frames:
        return "none_tracked"
    share = (frames - lost) / frames
    if share < MIN_TRACKED_SHARE and lost >= MIN_LOST_TO_FAIL:
        return "few_tracked"
    return "some_lost" if share < WARN_TRACKED_SHARE else "tracked"


def _message(verdict: str, summary: dict, records: Sequence[FrameRecord], unreadable: list[FrameRecord]) -> str | None:
    """The error or warning of ``verdict`` in one line (None for ``tracked`` and ``unknown``)."""
    frames = summary["frames"]
    if verdict == "none_tracked":
        skipped = next((record for record in records if record.skipped_reason), None)
        first = f" (frame {skipped.index}: {skipped.skipped_reason})" if skipped is not None else ""
        return f"tracked none of the {frames} frames{first}; likely causes: {NOTHING_TRACKED_CAUSES}"
    if verdict not in ("few_tracked", "some_lost"):
        return None
    lost, share = summary["lost"], summary["tracked_share"]
    where = f"{lost} lost, the first at frame {summary['first_lost']}"
    why = _likely_cause(summary, unreadable)
    if verdict == "few_tracked":
        return (f"tracked {summary['tracked']} of the {frames} frames ({100.0 * share:.0f} %; a run must track "
                f"{100.0 * MIN_TRACKED_SHARE:.0f} %): {where}; {why}")
    return (f"lost {lost} of the {frames} frames ({100.0 * (1.0 - share):.0f} %), the first at frame "
            f"{summary['first_lost']}; their poses are the motion model's guesses; {why}")


def _likely_cause(summary: dict, unreadable: list[FrameRecord]) -> str:
    """What the lost frames show (unreadable, few stereo points, or their points) and what it likely means."""
    if 2 * len(unreadable) >= summary["lost"]:
        return (f"{len(unreadable)} of them unreadable (frame {unreadable[0].index}: {unreadable[0].skipped_reason}); "
                "likely cause: image files missing, empty or corrupt")
    points = summary["stereo_points_median"]
    if points["lost"] is None or points["tracked"] is None:  # no lost frame read (or none tracked)
        return "likely causes: images missing or unreadable, or a calibration that does not fit them"
    evidence = f"(median {points['lost']:.0f}, the tracked frames {points['tracked']:.0f})"
    if points["lost"] < FEW_STEREO_POINTS_RATIO * points["tracked"]:
        return (f"the lost frames have few stereo points {evidence}; likely causes: their right images do not "
                "match the left (replaced, the same as the left, swapped, blank) or the images are too dark")
    return (f"the lost frames have their stereo points {evidence}; likely causes: motion too fast for the "
            "frame rate, frames missing or out of order, or the view filled by moving objects")


def _median(values: list[int]) -> float | None:
    """Median of ``values``, None for none."""
    return float(np.median(values)) if values else None

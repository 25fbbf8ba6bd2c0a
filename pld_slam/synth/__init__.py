"""The synthetic stereo world: the project's own deterministic test data.

A textured street scene made of quads (facades with windows, paving, road markings, parked
cars, poles, crates), a city of such streets on a grid, or a motorway (guard rails,
gantries, noise barriers, trees, distant buildings and hills), rendered as rectified
stereo pairs by a vectorised ray caster from the default camera or KITTI's (`CAMERAS`),
with exact ground-truth poses and per-frame masks of the pixels on moving objects.

- `build_scenario` builds one of `SCENARIOS` in memory; ``Scenario.render_frame(i)`` gives
  the left and right uint8 images and the left dynamic mask of frame ``i``.
- `write_sequence` writes a scenario in the KITTI odometry layout (plus dynamic masks);
  `ensure_sequence` only when the folder does not already hold it.
"""

from pld_slam.synth.render import SynthFrame, View, render_stereo_frame
from pld_slam.synth.scenarios import (
    CAMERAS,
    DEFAULT_FRAMES,
    MIN_FRAMES,
    MIN_LOOP_FRAMES,
    SCENARIOS,
    Scenario,
    build_scenario,
)
from pld_slam.synth.writer import SynthSummary, ensure_sequence, write_sequence

__all__ = [
    "CAMERAS",
    "DEFAULT_FRAMES",
    "MIN_FRAMES",
    "MIN_LOOP_FRAMES",
    "SCENARIOS",
    "Scenario",
    "SynthFrame",
    "SynthSummary",
    "View",
    "build_scenario",
    "ensure_sequence",
    "render_stereo_frame",
    "write_sequence",
]

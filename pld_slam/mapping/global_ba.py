"""Global bundle adjustment (paper, section "Loop correction": "when the system is finished, we
implemented the global BA to optimize all the keyframe pose and global map landmark state").

Every live keyframe is free but the first (the gauge `pld_slam.mapping.map_ba` always
holds, as ORB-SLAM2's global BA holds keyframe 0), with every landmark seen by at least
two keyframes; the residuals, loss,
rounds and outlier removal are local BA's (`pld_slam.mapping.map_ba`), with
``optimize.global_ba_max_nfev`` evaluations per solve.

Converged enough. The paper gives no stopping rule; this solve keeps local BA's (stop at a
0.1 % cost change, LSMR capped at 10 iterations per step), which leaves the flattest
direction of a long run, its drift, about where local BA put it. Solved to convergence
instead (`pld_slam.optim.bundle_adjustment.TO_CONVERGENCE`; ``benchmarks/ba_truth.py``),
it moves the drift, but away from the truth as often as toward it: most of the error left
is in the measurements, not in the solver (docs/decisions/0011-bundle-adjustment-solver.md,
"Global BA: converged enough").
"""

from pld_slam.config import Config
from pld_slam.geometry.camera import StereoCamera
from pld_slam.mapping.map import Map
from pld_slam.mapping.map_ba import BaReport, MapBaOptions, adjust_keyframes


def global_bundle_adjustment(world_map: Map, camera: StereoCamera, config: Config) -> BaReport | None:
    """Bundle-adjust the whole map, its first keyframe held fixed; None with nothing to adjust."""
    if len(world_map.keyframes) < 2:
        return None
    return adjust_keyframes(world_map, sorted(world_map.keyframes), camera, MapBaOptions.of(config),
                            config.optimize.global_ba_max_nfev)

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
instead (`pld_slam.optim.bundle_adjustment.TO_CONVERGENCE`; ``benchmarks/ba_truth.py``,
column "from run"), it moves the drift, but away from the truth as often as toward it.
ATE with global BA off, then converged from that run:

- KITTI 06: 0.0237 / 0.0271 m;
- raw 0005: 0.0892 / 0.0872;
- synthetic static, seeds 0-2: 0.0699 / 0.1068, 0.0735 / 0.0443, 0.0346 / 0.0453;
- synthetic loop, seeds 0-2: 0.0493 / 0.0524, 0.0609 / 0.0516, 0.0475 / 0.0473.

Started at the true poses (landmarks re-made there), the converged solve ends at the same
cost and no nearer the truth on the real extracts (0.0273, 0.0866), and on average 12 %
nearer on the synthetic static street (0.0827, 0.0428, 0.0303) and 7 % on the loop (0.0491,
0.0543, 0.0432). Most of the error left is in the measurements, not in the solver.
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

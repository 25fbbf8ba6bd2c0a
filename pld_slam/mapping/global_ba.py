"""Global bundle adjustment (paper, section "Loop correction": "when the system is finished, we
implemented the global BA to optimize all the keyframe pose and global map landmark state").

Every live keyframe is free but the first (the gauge `pld_slam.mapping.map_ba` always
holds, as ORB-SLAM2's global BA holds keyframe 0), with every landmark seen by at least
two keyframes; the residuals, loss,
rounds and outlier removal are local BA's (`pld_slam.mapping.map_ba`), with
``optimize.global_ba_max_nfev`` evaluations per solve.
"""

from pld_slam.config import Config
from pld_slam.geometry.camera import StereoCamera
from pld_slam.mapping.map import Map
from pld_slam.mapping.map_ba import BaReport, adjust_keyframes


def global_bundle_adjustment(world_map: Map, camera: StereoCamera, config: Config) -> BaReport | None:
    """Bundle-adjust the whole map, its first keyframe held fixed; None with nothing to adjust."""
    if len(world_map.keyframes) < 2:
        return None
    return adjust_keyframes(world_map, sorted(world_map.keyframes), camera, config, config.optimize.global_ba_max_nfev)

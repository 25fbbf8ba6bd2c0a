"""Local bundle adjustment (paper, section "Local BA"): the new keyframe's window of the map.

The window: the new keyframe and its ``mapping.local_ba_window`` strongest covisible
keyframes are free, with the landmarks they observe; every other keyframe that observes
those landmarks is held fixed, as in ORB-SLAM2 (it anchors the window to the rest of the
map). The solve itself, and what it leaves out, is `pld_slam.mapping.map_ba`.
"""

from pld_slam.config import Config
from pld_slam.geometry.camera import StereoCamera
from pld_slam.mapping.keyframe import KeyFrame
from pld_slam.mapping.map import Map
from pld_slam.mapping.map_ba import BaReport, MapBaOptions, adjust_keyframes


def local_bundle_adjustment(
    world_map: Map, keyframe: KeyFrame, camera: StereoCamera, config: Config
) -> BaReport | None:
    """Run local BA around ``keyframe`` and write the result into ``world_map``; None with nothing to adjust."""
    window = [keyframe.id, *world_map.covisibility.neighbours(keyframe.id, limit=config.mapping.local_ba_window)]
    return adjust_keyframes(world_map, window, camera, MapBaOptions.of(config), config.mapping.local_ba_max_nfev)

"""Landmarks on movers: which object each landmark was made on, and whether it outlives the object's rest.

A synthetic scenario knows which object every pixel shows (the renderer's object ids), so
each landmark can be traced to the object under the feature that created it, at its
keyframe's frame. `MoverLandmarks` follows a run keyframe by keyframe: it records the
owner of every new landmark, and for each mover that starts moving during the run (a
parked car pulling out, a pedestrian leaving the kerb) counts its landmarks still alive
at the ``keyframes_after``-th keyframe from the frame it started. The dynamic-scenes
issue asks for none: a map that keeps them tracks the car as if it were the world.

Two groups are counted apart. Landmarks made while the object rested are the issue's
subject: they were right when made and must leave once it moves. Landmarks made on it
after it started come from features the detectors missed; local mapping judges a new
landmark over the keyframes after its creation (`pld_slam.mapping.local_mapping`, step 2),
so only those at least ``mapping.min_observation_age`` keyframes old at the count are
counted, the newest not being judged yet.

Of the landmarks made at rest and alive at the count, those that no keyframe since the
object started had in view (in front of the camera, projecting inside its image) are
counted again apart: the camera had passed them before the object moved, so nothing in
any frame could tell that they left. They stay in the first count; the second says how
many of it no method could have removed.
"""

from collections.abc import Callable, Collection
from dataclasses import dataclass, field
from functools import partial

import numpy as np

from pld_slam.config import MappingConfig
from pld_slam.localisation.local_map import points_in_view
from pld_slam.mapping.keyframe import KeyFrame
from pld_slam.mapping.landmarks import Landmarks, PointLandmarks
from pld_slam.mapping.map import Map
from pld_slam.synth.scenarios import Scenario

GROUPS = ("at rest", "at rest, out of view", "moving")
"""The groups of `MoverLandmarks.rows`: made at rest; of those, in no keyframe's view since the
object started; made while it moved (module docstring)."""


def start_frames(world: Scenario) -> dict[int, int]:
    """Object id -> the first frame at which it moves, for the movers of ``world`` that rest first."""
    starts = {}
    for mover in world.scene.moving:
        moving = [frame for frame in range(world.n_frames) if mover.moves_at(frame)]
        if moving and moving[0] > 0:
            starts[mover.object_id] = moving[0]
    return starts


def feature_pixel(kind: Landmarks, keyframe: KeyFrame, feature: int) -> np.ndarray:
    """Left pixel (2,) of a keyframe's feature of ``kind``: a point's keypoint, a line's midpoint."""
    if isinstance(kind, PointLandmarks):
        return keyframe.features.keypoints.uv[feature]
    return keyframe.features.lines.endpoints[feature].reshape(2, 2).mean(axis=0)


def landmark_owner(
    world_map: Map, kind: Landmarks, landmark: int, object_ids: Callable[[int], np.ndarray]
) -> int | None:
    """The object (id) under the feature that made ``landmark``, in the object-id image (H, W)
    ``object_ids(frame)``; where local BA has dropped that observation, under its earliest
    remaining one. None for a landmark without observations (culled)."""
    observers = kind.observers[landmark]
    if not observers:
        return None
    keyframe_id = int(kind.first_keyframe[landmark])
    if keyframe_id not in observers:
        keyframe_id = min(observers)
    keyframe = world_map.keyframes[keyframe_id]
    image = object_ids(keyframe.frame_index)
    u, v = np.rint(feature_pixel(kind, keyframe, observers[keyframe_id])).astype(np.int64)
    return int(image[np.clip(v, 0, image.shape[0] - 1), np.clip(u, 0, image.shape[1] - 1)])


@dataclass(frozen=True)
class LandmarkOrigin:
    """Where and when one landmark was made: the object under its feature, the frame and
    the keyframe's rank among those the watch has seen."""

    owner: int
    frame: int
    rank: int

    def at_rest_on(self, mover: int, start: int) -> bool:
        """Whether the landmark was made on ``mover`` before it started moving at frame ``start``."""
        return self.owner == mover and self.frame < start


@dataclass
class MoverLandmarks:
    """The landmarks of a run on the movers of ``world`` (module docstring).

    Call `on_keyframe` after each keyframe's insertion; `rows` then lists, per mover that
    started moving, its landmarks made (points, lines) and, ``keyframes_after`` keyframes
    from its start, those made at rest and those made while moving (judged: at least
    ``judgement_age`` keyframes old, the run's ``mapping.min_observation_age``) still alive
    (None where the run ended first).
    """

    world: Scenario
    keyframes_after: int = 5
    judgement_age: int = MappingConfig.min_observation_age
    made: tuple[dict[int, LandmarkOrigin], dict[int, LandmarkOrigin]] = field(
        init=False, default_factory=lambda: ({}, {})
    )
    starts: dict[int, int] = field(init=False)
    keyframes_since_start: dict[int, int] = field(init=False)
    alive_after: dict[int, dict[str, tuple[int, int]]] = field(init=False, default_factory=dict)
    in_view_since_start: dict[int, tuple[set[int], set[int]]] = field(init=False, default_factory=dict)
    rendered: dict[int, np.ndarray] = field(init=False, default_factory=dict)
    keyframes_seen: int = field(init=False, default=0)

    def __post_init__(self) -> None:
        self.starts = start_frames(self.world)
        self.keyframes_since_start = dict.fromkeys(self.starts, 0)

    def on_keyframe(self, world_map: Map, keyframe_id: int) -> None:
        """Record the owners of the landmarks keyframe ``keyframe_id`` (just inserted) made, and
        count alive the landmarks of the movers whose ``keyframes_after``-th keyframe it is."""
        frame = world_map.keyframes[keyframe_id].frame_index
        self.keyframes_seen += 1
        for kind, made in zip(world_map.kinds, self.made):
            for landmark in np.flatnonzero(kind.first_keyframe[: len(kind)] == keyframe_id).tolist():
                owner = landmark_owner(world_map, kind, landmark, self.object_ids)
                if owner is not None:
                    made[landmark] = LandmarkOrigin(owner, frame, self.keyframes_seen)
        for mover, start in self.starts.items():
            if frame < start or mover in self.alive_after:
                continue
            self.note_in_view(world_map, world_map.keyframes[keyframe_id], mover, start)
            self.keyframes_since_start[mover] += 1
            if self.keyframes_since_start[mover] == self.keyframes_after:
                self.alive_after[mover] = self.alive_by_group(world_map, mover, start)

    def note_in_view(self, world_map: Map, keyframe: KeyFrame, mover: int, start: int) -> None:
        """Add the alive points and lines of ``mover`` made at rest (before frame ``start``) that
        ``keyframe`` has in view (a point, a line's midpoint: `points_in_view`) to
        ``in_view_since_start[mover]``."""
        seen_by_kind = self.in_view_since_start.setdefault(mover, (set(), set()))
        for kind, made, seen in zip(world_map.kinds, self.made, seen_by_kind):
            ids = np.array([landmark for landmark, m in made.items()
                            if m.at_rest_on(mover, start) and kind.alive[landmark]], dtype=np.int64)
            seen.update(ids[points_in_view(self.world.camera, keyframe.T_c_w, kind.centres(ids))[2]].tolist())

    def object_ids(self, frame: int) -> np.ndarray:
        """The renderer's object id of every left pixel (H, W) of ``frame`` (rendered once)."""
        if frame not in self.rendered:
            self.rendered[frame] = self.world.render_views(frame)[0].object_id
        return self.rendered[frame]

    def made_on(self, mover: int) -> tuple[int, int]:
        """Points and lines ever made on ``mover``."""
        points, lines = (sum(m.owner == mover for m in made.values()) for made in self.made)
        return points, lines

    def alive_by_group(self, world_map: Map, mover: int, start: int) -> dict[str, tuple[int, int]]:
        """Points and lines of ``mover`` (which started at frame ``start``) alive now: those made
        at rest, of those the ones no keyframe since ``start`` had in view (`note_in_view`), and
        those made while it moved that are at least ``judgement_age`` keyframes old."""
        judged = self.keyframes_seen - self.judgement_age
        at_rest = partial(LandmarkOrigin.at_rest_on, mover=mover, start=start)
        return {
            "at rest": self.alive(world_map, at_rest),
            "at rest, out of view": self.alive(world_map, at_rest, self.in_view_since_start.get(mover, (set(), set()))),
            "moving": self.alive(world_map, lambda m: m.owner == mover and m.frame >= start and m.rank <= judged),
        }

    def alive(self, world_map: Map, chosen: Callable[[LandmarkOrigin], bool],
              left_out: tuple[Collection[int], Collection[int]] = ((), ())) -> tuple[int, int]:
        """Points and lines alive in ``world_map`` now among those whose `LandmarkOrigin` is ``chosen``,
        but for the points and lines ``left_out``."""
        points, lines = (
            sum(bool(kind.alive[landmark]) for landmark, m in made.items() if chosen(m) and landmark not in out)
            for kind, made, out in zip(world_map.kinds, self.made, left_out)
        )
        return points, lines

    def rows(self) -> list[dict]:
        """One row per mover that started moving (class docstring)."""
        rows = []
        after = f"KF+{self.keyframes_after}"
        for mover, start in self.starts.items():
            made = self.made_on(mover)
            row = {"object": mover, "starts at frame": start, "points made": made[0], "lines made": made[1]}
            for group in GROUPS:
                alive = self.alive_after.get(mover, {}).get(group, (None, None))
                row[f"points made {group}, alive at {after}"] = alive[0]
                row[f"lines made {group}, alive at {after}"] = alive[1]
            rows.append(row)
        return rows

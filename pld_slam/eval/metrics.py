"""Accuracy of an estimated trajectory against ground truth, through evo.

The steps, each public:

1. `associate`: pair estimate and ground-truth poses by timestamp
   (``evo.core.sync.associate_trajectories``) or by row index (KITTI files).
2. `fit_alignment`: Umeyama alignment of the matched estimate positions onto the ground
   truth (``evo.core.geometry.umeyama_alignment``): SE(3), Sim(3) or none.
3. `ate_errors` (evo ``APE``, translation part) and `relative_pose_errors` (evo ``RPE``).
4. `evaluate`: all of the above plus the KITTI devkit drift (`kitti_devkit`) and the
   estimate's scale (`Alignment.estimate_scale` of the Sim(3) fit, `path_ratio`), as an
   `EvalResult`.

Every error metric of `evaluate` is computed on the aligned estimate. RPE and the KITTI
drift do not change under an SE(3) alignment; under Sim(3) they see the scale-corrected
estimate, which is what one wants for a monocular run. The scale figures do not depend
on ``align``: a stereo run's scale error (a path ~1 % too long on KITTI) must show
whichever alignment the ATE used. Both read as the estimate's size over the truth's,
above 1 for an estimate too long: the Umeyama scale (which takes the estimate onto the
truth) is inverted for that.
"""

from dataclasses import asdict, dataclass

import numpy as np
from evo import main_ape
from evo.core.filters import FilterException
from evo.core.geometry import GeometryException, umeyama_alignment
from evo.core.metrics import APE, RPE, PoseRelation, StatisticsType, Unit
from evo.core.result import Result
from evo.core.sync import SyncException, associate_trajectories
from evo.core.trajectory import PoseTrajectory3D

from pld_slam.errors import TrajectoryError
from pld_slam.eval.kitti_devkit import kitti_relative_errors
from pld_slam.trajectory import Trajectory

ALIGNMENTS = ("se3", "sim3", "none")
DELTA_UNITS = {"frames": Unit.frames, "m": Unit.meters}


@dataclass(frozen=True)
class EvalResult:
    """Accuracy figures of one estimate; the keys of ``pld-slam eval --json``.

    Attributes
    ----------
    ate_rmse_m : float
        RMSE of the position error after alignment [m].
    ate_rot_rmse_deg : float
        RMSE of the absolute rotation error [deg]: the angle of ``R_gt^T R_est`` per
        matched pose (evo APE ``rotation_angle_deg``) after `fit_orientation_alignment`
        (none with ``align="none"``).
    ate_sim3_rmse_m : float
        RMSE of the position error after the Sim(3) alignment [m], whatever ``align``:
        what is left once the scale error is taken out.
    sim3_scale : float or None
        The estimate's size over the ground truth's by the Sim(3) alignment
        (`Alignment.estimate_scale`: 1 / its Umeyama scale), whatever ``align``; 1.01 =
        the estimate is 1 % too large. None when the ground truth hardly moves
        (`scale_is_measurable`).
    path_ratio : float or None
        `path_ratio`: the estimate's path length over the ground truth's, over the matched
        poses; None when the ground truth hardly moves (`scale_is_measurable`).
    rpe_trans_rmse_m, rpe_rot_rmse_deg : float
        RMSE of the relative pose error between consecutive matched poses [m], [deg].
    t_rel_pct, r_rel_deg_per_100m : float or None
        KITTI devkit drift [%] and [deg / 100 m]; None when the path is under 100 m.
    n_matched : int
        Number of matched (estimate, ground truth) pose pairs.
    """

    ate_rmse_m: float
    ate_rot_rmse_deg: float
    ate_sim3_rmse_m: float
    sim3_scale: float | None
    path_ratio: float | None
    rpe_trans_rmse_m: float
    rpe_rot_rmse_deg: float
    t_rel_pct: float | None
    r_rel_deg_per_100m: float | None
    n_matched: int

    def as_dict(self) -> dict:
        """The fields as a JSON-ready dict."""
        return asdict(self)


@dataclass(frozen=True)
class Alignment:
    """Similarity taking estimate positions onto the ground truth.

    A position ``p`` becomes ``scale * rotation @ p + translation``; an orientation
    ``R_w_c`` becomes ``rotation @ R_w_c``. ``rotation`` is (3, 3), ``translation`` (3,).
    """

    rotation: np.ndarray
    translation: np.ndarray
    scale: float

    def apply(self, traj: Trajectory) -> Trajectory:
        """``traj`` (all its poses) moved into the ground-truth world."""
        poses = traj.poses.copy()
        poses[:, :3, :3] = self.rotation @ traj.poses[:, :3, :3]
        poses[:, :3, 3] = self.scale * traj.positions @ self.rotation.T + self.translation
        return Trajectory(traj.timestamps, poses)

    @property
    def estimate_scale(self) -> float | None:
        """The estimate's size over the ground truth's: 1 / `scale`; None for a `scale` of 0.

        `scale` takes the estimate onto the ground truth, so an estimate 1 % too large has
        1 / 1.01; this reads as `path_ratio` does, above 1 for an estimate too large. A
        Sim(3) fit onto a ground truth standing at one point has scale 0.
        """
        return 1.0 / self.scale if self.scale > 0.0 else None


IDENTITY = Alignment(rotation=np.eye(3), translation=np.zeros(3), scale=1.0)


def _to_evo(traj: Trajectory) -> PoseTrajectory3D:
    return PoseTrajectory3D(poses_se3=list(traj.poses), timestamps=traj.timestamps)


def _from_evo(traj: PoseTrajectory3D) -> Trajectory:
    return Trajectory(traj.timestamps, np.array(traj.poses_se3))


def _associate_by_index(
    groundtruth: Trajectory, estimate: Trajectory
) -> tuple[Trajectory, Trajectory]:
    if len(estimate) > len(groundtruth):
        raise TrajectoryError(
            f"the estimate has {len(estimate)} poses but the ground truth only "
            f"{len(groundtruth)}; poses matched by index need an estimate no longer "
            "than the ground truth"
        )
    return groundtruth.head(len(estimate)), estimate


def _associate_by_time(
    groundtruth: Trajectory, estimate: Trajectory, max_diff: float
) -> tuple[Trajectory, Trajectory]:
    if len(groundtruth) == 0 or len(estimate) == 0:
        raise TrajectoryError("cannot associate an empty trajectory")
    try:
        gt, est = associate_trajectories(
            _to_evo(groundtruth), _to_evo(estimate), max_diff=max_diff
        )
    except SyncException:
        raise TrajectoryError(
            f"no estimate time is within {max_diff:g} s of a ground-truth time (estimate {time_span(estimate)}; "
            f"ground truth {time_span(groundtruth)})"
        ) from None
    return _from_evo(gt), _from_evo(est)


def time_span(trajectory: Trajectory) -> str:
    """``N poses, FIRST to LAST s``: what a trajectory's timestamps cover, for messages."""
    return f"{len(trajectory)} poses, {trajectory.timestamps[0]:.3f} to {trajectory.timestamps[-1]:.3f} s"


def associate(
    groundtruth: Trajectory, estimate: Trajectory, by_index: bool = False, max_diff: float = 0.01
) -> tuple[Trajectory, Trajectory]:
    """Matched ground-truth and estimate poses, equal in number and in order.

    Parameters
    ----------
    groundtruth, estimate : Trajectory
    by_index : bool
        Match row i with row i (KITTI files carry no timestamps). An estimate shorter
        than the ground truth (a run stopped early) is matched with the first rows;
        a longer one raises `TrajectoryError`.
    max_diff : float
        Largest time difference of a matched pair [s] when matching by timestamp.
    """
    if by_index:
        return _associate_by_index(groundtruth, estimate)
    return _associate_by_time(groundtruth, estimate, max_diff)


def _check_alignment_name(align: str) -> None:
    if align not in ALIGNMENTS:
        raise TrajectoryError(f"unknown alignment {align!r}; expected one of {ALIGNMENTS}")


def fit_alignment(groundtruth: Trajectory, estimate: Trajectory, align: str = "se3") -> Alignment:
    """Umeyama alignment (evo) of matched estimate positions onto ground-truth positions.

    ``groundtruth`` and ``estimate`` are matched pose by pose (see `associate`); ``align``
    is ``se3`` (rotation and translation), ``sim3`` (also scale) or ``none``.

    Positions on one line (a short straight drive, a vehicle standing still) leave the
    rotation about that line free, and Umeyama refuses them; so do fewer than 3 poses.
    We then anchor the estimate on the ground truth at the first matched pose (rotation
    and position), the convention of trajectories that both start at identity, with the
    scale (``sim3``) from the spread of the positions about their means.
    """
    _check_alignment_name(align)
    if align == "none":
        return IDENTITY
    try:
        if len(estimate) < 3:
            raise GeometryException("fewer than 3 poses")
        rotation, translation, scale = umeyama_alignment(
            estimate.positions.T, groundtruth.positions.T, with_scale=align == "sim3"
        )
    except GeometryException:
        return _first_pose_alignment(groundtruth, estimate, with_scale=align == "sim3")
    return Alignment(rotation, translation, float(scale))


def fit_orientation_alignment(groundtruth: Trajectory, estimate: Trajectory) -> Alignment:
    """The world rotation taking the estimate's orientations closest to the ground truth's.

    The rotation ``R`` minimising ``sum_i ||R_gt_i - R @ R_est_i||_F^2`` over the matched
    poses: the projection onto SO(3) (SVD) of ``sum_i R_gt_i R_est_i^T``. The rotation
    error is measured after this alignment, not after the position alignment of the ATE:
    positions on a nearly straight drive leave the rotation about the direction of travel
    to noise, and on a 12-frame straight synthetic run the position alignment put a
    constant 3.9 deg roll into every pose whose orientations were right to 0.3 deg.
    """
    correlation = np.einsum("nij,nkj->ik", groundtruth.poses[:, :3, :3], estimate.poses[:, :3, :3])
    u, _, vt = np.linalg.svd(correlation)
    sign = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    return Alignment(rotation=u @ sign @ vt, translation=np.zeros(3), scale=1.0)


def _first_pose_alignment(groundtruth: Trajectory, estimate: Trajectory, with_scale: bool) -> Alignment:
    """The similarity taking the estimate's first pose onto the ground truth's first pose."""
    rotation = groundtruth.poses[0, :3, :3] @ estimate.poses[0, :3, :3].T
    scale = 1.0
    if with_scale:
        spread_gt = np.linalg.norm(groundtruth.positions - groundtruth.positions.mean(axis=0))
        spread_est = np.linalg.norm(estimate.positions - estimate.positions.mean(axis=0))
        scale = spread_gt / spread_est if spread_est > 0.0 else 1.0
    translation = groundtruth.positions[0] - scale * rotation @ estimate.positions[0]
    return Alignment(rotation, translation, float(scale))


MIN_SCALE_LEVER = 10.0
"""The scale figures need the ground truth's positions to spread (RMS distance from their
centroid) over at least this many times the Sim(3) ATE: the scale is then known to about a
tenth. EuRoC's static extract (a camera standing still, 6 mm of motion-capture noise) read
a Sim(3) scale of 2.25 and a path ratio of 3.5 without this."""


def scale_is_measurable(groundtruth: Trajectory, ate_sim3_rmse_m: float) -> bool:
    """Whether ``groundtruth``'s positions spread enough for a scale (`MIN_SCALE_LEVER`)."""
    positions = groundtruth.positions
    spread = float(np.sqrt(np.mean(np.sum((positions - positions.mean(axis=0)) ** 2, axis=1))))
    return spread > 0.0 and spread >= MIN_SCALE_LEVER * ate_sim3_rmse_m


def path_ratio(groundtruth: Trajectory, estimate: Trajectory) -> float | None:
    """Path length of the estimate over the ground truth's; None when the ground truth does not move.

    ``groundtruth`` and ``estimate`` are matched pose by pose (see `associate`): each path is
    the sum of the distances between consecutive matched positions (`Trajectory.path_length`),
    so poses only one of them has do not count. Noise lengthens a path, so on a short or
    slow path the ratio reads above the scale error (the Sim(3) fit's
    `Alignment.estimate_scale` does not).
    """
    truth = groundtruth.path_length()
    return estimate.path_length() / truth if truth > 0.0 else None


def _matched(
    groundtruth: Trajectory, estimate: Trajectory, by_index: bool, max_diff: float
) -> tuple[Trajectory, Trajectory]:
    """Matched ground truth and estimate (`associate`), at least 2 pairs of them."""
    gt, est = associate(groundtruth, estimate, by_index, max_diff)
    if len(gt) < 2:
        raise TrajectoryError(
            f"only {len(gt)} estimate pose(s) matched the ground truth; need at least 2 "
            f"(check the timestamps, max_diff = {max_diff} s, or match by index)"
        )
    return gt, est


def ate_result(
    groundtruth: Trajectory,
    estimate: Trajectory,
    name: str,
    align: str = "se3",
    by_index: bool = False,
    max_diff: float = 0.01,
) -> Result:
    """The ATE of ``estimate`` (named ``name``) as evo's `Result`, what ``evo_res`` compares.

    evo's APE of the position (``main_ape.ape``) between the matched poses, the estimate
    aligned first as `evaluate` aligns it (``align``; `fit_alignment`), so the result's
    RMSE is `evaluate`'s ``ate_rmse_m``; ``info["alignment"]`` says which alignment. The
    title names the metric and alignment only: ``evo_res`` compares results of one title.
    """
    gt, est = _matched_and_aligned(groundtruth, estimate, align, by_index, max_diff)
    result = main_ape.ape(_to_evo(gt), _to_evo(est), PoseRelation.translation_part)
    result.info.update(est_name=name, ref_name="ground truth", alignment=align, title=f"ATE ({align} alignment)")
    return result


def _matched_and_aligned(
    groundtruth: Trajectory, estimate: Trajectory, align: str, by_index: bool, max_diff: float
) -> tuple[Trajectory, Trajectory]:
    """Matched ground truth and the matched estimate aligned onto it."""
    _check_alignment_name(align)
    gt, est = _matched(groundtruth, estimate, by_index, max_diff)
    return gt, fit_alignment(gt, est, align).apply(est)


def _absolute_error(groundtruth: Trajectory, estimate: Trajectory, relation: PoseRelation) -> APE:
    ape = APE(relation)
    ape.process_data((_to_evo(groundtruth), _to_evo(estimate)))
    return ape


def _absolute_rmse(groundtruth: Trajectory, estimate: Trajectory, relation: PoseRelation) -> float:
    """RMSE of evo's APE of ``relation`` between matched poses, as they are (no alignment)."""
    return float(_absolute_error(groundtruth, estimate, relation).get_statistic(StatisticsType.rmse))


def ate_errors(
    groundtruth: Trajectory,
    estimate: Trajectory,
    align: str = "se3",
    by_index: bool = False,
    max_diff: float = 0.01,
) -> tuple[np.ndarray, np.ndarray]:
    """Position error of each matched estimate pose after alignment (evo APE).

    Returns
    -------
    timestamps : np.ndarray
        (M,) estimate times of the matched poses [s].
    errors : np.ndarray
        (M,) distance between aligned estimate and ground-truth positions [m].
    """
    gt, est = _matched_and_aligned(groundtruth, estimate, align, by_index, max_diff)
    return est.timestamps, _absolute_error(gt, est, PoseRelation.translation_part).error


def _rpe_rmse(
    groundtruth: Trajectory, estimate: Trajectory, relation: PoseRelation, delta, unit: Unit
) -> float:
    rpe = RPE(relation, delta=delta, delta_unit=unit, pairs_from_reference=True)
    rpe.process_data((_to_evo(groundtruth), _to_evo(estimate)))
    return float(rpe.get_statistic(StatisticsType.rmse))


def relative_pose_errors(
    groundtruth: Trajectory, estimate: Trajectory, delta: float = 1, delta_unit: str = "frames"
) -> tuple[float, float]:
    """RMSE of evo's RPE over consecutive pose pairs ``delta`` apart.

    Parameters
    ----------
    groundtruth, estimate : Trajectory
        Matched pose by pose (see `associate`).
    delta : float
        Pair spacing: frames (an integer) or metres of ground-truth path.
    delta_unit : str
        ``frames`` or ``m``.

    Returns
    -------
    translation_rmse_m, rotation_rmse_deg : float
    """
    if delta_unit not in DELTA_UNITS:
        raise TrajectoryError(f"unknown RPE delta unit {delta_unit!r}; expected frames or m")
    unit = DELTA_UNITS[delta_unit]
    try:
        return (
            _rpe_rmse(groundtruth, estimate, PoseRelation.translation_part, delta, unit),
            _rpe_rmse(groundtruth, estimate, PoseRelation.rotation_angle_deg, delta, unit),
        )
    except FilterException:
        raise TrajectoryError(
            f"no pose pairs {delta} {delta_unit} apart among {len(groundtruth)} poses "
            f"({groundtruth.path_length():.1f} m of path)"
        ) from None


def evaluate(
    groundtruth: Trajectory,
    estimate: Trajectory,
    align: str = "se3",
    by_index: bool = False,
    max_diff: float = 0.01,
) -> EvalResult:
    """ATE, per-frame RPE, KITTI drift and scale of ``estimate`` against ``groundtruth``.

    Parameters
    ----------
    groundtruth, estimate : Trajectory
        ``T_w_c`` poses; their world frames may differ (the alignment removes that).
    align : str
        ``se3`` (default), ``sim3`` or ``none``; applied before every error metric but the
        Sim(3) ATE. The scale figures are of the matched estimate before any alignment.
    by_index, max_diff
        How poses are matched; see `associate`.
    """
    _check_alignment_name(align)
    gt, matched = _matched(groundtruth, estimate, by_index, max_diff)
    est = fit_alignment(gt, matched, align).apply(matched)
    rpe_trans, rpe_rot = relative_pose_errors(gt, est)
    t_rel, r_rel = kitti_relative_errors(gt.poses, est.poses)
    oriented = est if align == "none" else fit_orientation_alignment(gt, est).apply(est)
    sim3 = fit_alignment(gt, matched, "sim3")
    ate_sim3 = _absolute_rmse(gt, sim3.apply(matched), PoseRelation.translation_part)
    measurable = scale_is_measurable(gt, ate_sim3)
    return EvalResult(
        ate_rmse_m=_absolute_rmse(gt, est, PoseRelation.translation_part),
        ate_rot_rmse_deg=_absolute_rmse(gt, oriented, PoseRelation.rotation_angle_deg),
        ate_sim3_rmse_m=ate_sim3,
        sim3_scale=sim3.estimate_scale if measurable else None,
        path_ratio=path_ratio(gt, matched) if measurable else None,
        rpe_trans_rmse_m=rpe_trans,
        rpe_rot_rmse_deg=rpe_rot,
        t_rel_pct=t_rel,
        r_rel_deg_per_100m=r_rel,
        n_matched=len(gt),
    )

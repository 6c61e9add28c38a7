"""Marker self-calibration from a log of mutual observations (SPEC "Marker
calibration"): :func:`calibrate_markers`.  Any rig: robots with one camera,
or with several cameras of any lens (observations keyed ``ROBOT/CAMERA``,
fitted as rays through each camera's mount and lens).

Every frame is localized on its own with the given rig (``localize``, pair
by pair, chained through the frame's robots), then one bundle adjustment
(:mod:`mutloc.core.calibration`) refines every frame's poses and every
marker's position together.  The markers' covariance, with the scale held,
gives ``position_sigma``; its eigen-decomposition names the weakly
determined combinations, and a log that cannot determine the markers raises
:class:`~mutloc.errors.UnobservableMarkersError`.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from .core.calibration import HUBER_K, BundleProblem, adjust, constraint_jacobian, null_space, start_depths
from .core.consistency import DEFAULT_CONFIDENCE, chi2_quantile
from .core.geometry import so3_log
from .core.observations import ObservationSet
from .core.pose import Pose
from .core.rig import MarkerKind, Rig
from .errors import (InconsistentObservationsError, InputError, MutlocError, UnknownMarkerError,
                     UnobservableMarkersError, positive_number)

__all__ = ["calibrate_markers", "CalibrationResult", "MarkerCalibration", "WeakDirection", "parse_scale"]

#: Observations a pair of robots needs in a frame to be localized on its own
#: (three fit several poses exactly; the fourth picks one).
MIN_PAIR_OBSERVATIONS = 4
#: The constrained information's smallest eigenvalue below this fraction of
#: its largest: some combination of markers is not determined at all.
SINGULAR_RATIO = 1e-10
#: A combination of markers known no better than this (1 sigma, metres, at
#: the stated pixel noise) is not determined by the log.
MAX_SIGMA_M = 0.5
#: Without --prior-sigma, the combinations the log determines worse than
#: this (1 sigma, metres; two upright robots leave some) are held near the
#: given rig, taken as good to it along them (a tape measure's centimetre).
WEAK_PRIOR_SIGMA_M = 0.01
#: The held combinations' weight in the fit, relative to ``weak_sigma``'s:
#: taken from the given rig, not fused with the log's weak say along them.
HOLD_STIFFNESS = 1e4
#: A combination whose sigma is above this many times the median one (and
#: above :data:`WEAK_MIN_M`) is reported as weakly determined.
WEAK_RATIO = 4.0
WEAK_MIN_M = 0.003
#: Each frame's start is solved with at least this pixel noise (the given
#: rig is only approximate: its consistency test must not refuse the rig's
#: error, only wrong detections), and an observation farther than START_GATE_PX
#: from where the start puts it is a wrong detection, set aside and reported.
START_SIGMA_PX = 3.0
START_GATE_PX = 50.0
#: The detection noise behind the reported sigmas is measured from the fit's
#: residuals (the a-posteriori variance factor, as a bundle adjuster or
#: OpenCV's calibrateCamera reports it) once the fit has this many degrees
#: of freedom; below the stated noise, its upper two-sigma bound is used
#: (as the tracker's measured noise).
NOISE_MIN_DOF = 20
NOISE_FLOOR = 0.01
# Rounds of (measure the noise, weigh the priors by it, fit), and the ratio
# under which the measured noise counts as settled.
_NOISE_ROUNDS = 3
_NOISE_SETTLED = 1.1
# Frames this close in relative pose count as one pose (degree, metre).
SAME_POSE_DEG = 3.0
SAME_POSE_M = 0.01

_AXIS_WORDS = (("moving {r}'s markers right (+x)", "moving {r}'s markers left (-x)"),
               ("lowering {r}'s markers (+y)", "raising {r}'s markers (-y)"),
               ("moving {r}'s markers forward (+z)", "moving {r}'s markers back (-z)"))
# A body's frame (REP 103 base_link): x forward, y left, z up.
_BODY_AXIS_WORDS = (("moving {r}'s markers forward (+x)", "moving {r}'s markers back (-x)"),
                    ("moving {r}'s markers left (+y)", "moving {r}'s markers right (-y)"),
                    ("raising {r}'s markers (+z)", "lowering {r}'s markers (-z)"))
# What tilting means to a robot whose frame is its camera's, and to a body (said once every robot is one).
_ROLL_WORDS = (("Roll one robot about its optical axis during the recording (or tilt it)",
                "Tilt one robot (roll or pitch it) during the recording"),
               ("roll one robot about its optical axis during the recording (or tilt it)",
                "tilt one robot (roll or pitch it) during the recording"),
               ("rolling one robot about its optical axis", "tilting one robot (roll or pitch)"),
               ("roll one robot about its optical axis", "tilt one robot (roll or pitch it)"),
               ("The robots hardly roll relative", "The robots hardly tilt relative"))


# ---------------------------------------------------------------------------
# results
# ---------------------------------------------------------------------------


@dataclass
class MarkerCalibration:
    """One marker: ``old`` (the given rig's) and ``new`` position (own robot's
    frame, metres) and ``sigma``, the new position's 1-sigma per axis."""

    name: str
    robot: str
    old: np.ndarray
    new: np.ndarray
    sigma: np.ndarray
    #: For a tag (calibrated as a rigid body from its corners): its rotation
    #: vector (radians, robot frame) before and after, and the new one's
    #: 1-sigma per axis of the robot frame (radians, left perturbation).
    old_rotation: np.ndarray | None = None
    new_rotation: np.ndarray | None = None
    rotation_sigma: np.ndarray | None = None

    @property
    def change(self) -> np.ndarray:
        return self.new - self.old

    @property
    def rotation_change_deg(self) -> float | None:
        """The angle (degrees) between the old and the new rotation of a tag; None for other markers."""
        if self.old_rotation is None or self.new_rotation is None:
            return None
        from .core.geometry import rotation_error_deg, so3_exp

        return rotation_error_deg(so3_exp(self.new_rotation), so3_exp(self.old_rotation))

    def to_dict(self) -> dict[str, Any]:
        d = {"robot": self.robot, "old": self.old.tolist(), "new": self.new.tolist(),
             "change": self.change.tolist(), "change_m": float(np.linalg.norm(self.change)),
             "position_sigma": self.sigma.tolist()}
        if self.new_rotation is not None:
            d.update(old_rotation=self.old_rotation.tolist(), rotation=self.new_rotation.tolist(),
                     rotation_change_deg=self.rotation_change_deg, rotation_sigma=self.rotation_sigma.tolist())
        return d


@dataclass
class WeakDirection:
    """A combination of marker positions the log determines weakly: moving every
    marker by ``sigma_m * shifts[name]`` changes the pixels as little as one
    standard deviation of noise does.  ``description`` says it in words,
    ``advice`` what motion during the recording would determine it."""

    sigma_m: float
    description: str
    advice: str
    shifts: dict[str, list[float]]
    #: Determined by the log worse than the given rig is taken to be
    #: (``sigma_m``, the log's own, inf when not at all): held near the
    #: given rig (calibrate_markers' ``weak_sigma``).
    held: bool = False

    def to_dict(self) -> dict[str, Any]:
        return {"sigma_m": self.sigma_m if math.isfinite(self.sigma_m) else None, "description": self.description,
                "advice": self.advice, "shifts": self.shifts, "held": self.held}


@dataclass
class CalibrationResult:
    """What :func:`calibrate_markers` found.

    ``rig`` is the new rig in rig-file form (each calibrated marker with its
    new ``position`` and ``position_sigma``); ``markers`` the per-marker old,
    new, change and sigma; ``weak_directions`` the weakly determined
    combinations, weakest first; ``covariance`` (3k, 3k) the joint covariance
    of the calibrated markers (``covariance_markers``, in that order, x y z
    each) with the scale held.
    """

    rig: dict[str, Any]
    markers: dict[str, MarkerCalibration]
    weak_directions: list[WeakDirection]
    scale: list[tuple[str, str, float]]
    pixel_sigma: float
    covariance: np.ndarray
    covariance_markers: list[str]
    frames_total: int
    frames_used: int
    observations_used: int
    reprojection_rms_px: float
    chi2: float
    dof: int
    iterations: int
    converged: bool
    prior_sigma: float | None = None
    #: The detection noise (px, per image axis) the fit's residuals show,
    #: and the noise behind ``position_sigma`` and ``rotation_sigma``: the
    #: measured one once the log has enough degrees of freedom (below the
    #: stated ``pixel_sigma``: its upper two-sigma bound), else ``pixel_sigma``.
    measured_pixel_sigma: float | None = None
    sigma_noise_px: float | None = None
    outliers: list[dict[str, Any]] = field(default_factory=list)
    unobserved: list[str] = field(default_factory=list)
    skipped_frames: list[dict[str, Any]] = field(default_factory=list)
    poses: list[dict[str, Any]] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        """JSON form (the new rig, the per-marker table, weak directions, fit figures)."""
        return {
            "rig": self.rig,
            "markers": {n: m.to_dict() for n, m in self.markers.items()},
            "weak_directions": [w.to_dict() for w in self.weak_directions],
            "scale": [{"markers": [a, b], "distance_m": d} for a, b, d in self.scale],
            "pixel_sigma": self.pixel_sigma, "measured_pixel_sigma": self.measured_pixel_sigma,
            "sigma_noise_px": self.sigma_noise_px, "prior_sigma": self.prior_sigma,
            "frames_total": self.frames_total, "frames_used": self.frames_used,
            "observations_used": self.observations_used, "reprojection_rms_px": self.reprojection_rms_px,
            "chi2": self.chi2, "dof": self.dof, "iterations": self.iterations, "converged": self.converged,
            "outliers": self.outliers, "unobserved": self.unobserved, "skipped_frames": self.skipped_frames,
        }

    def _noise_words(self) -> str:
        noise = self.pixel_sigma if self.sigma_noise_px is None else self.sigma_noise_px
        shown = "" if self.measured_pixel_sigma is None else f"the residuals show {self.measured_pixel_sigma:.3g} px"
        if noise == self.pixel_sigma:
            return f"sigmas for the stated {noise:g} px noise" + (f" ({shown})" if shown else "")
        return f"sigmas for the measured {noise:.3g} px noise ({shown}; stated {self.pixel_sigma:g} px)"

    def summary(self) -> str:
        """The per-marker table (old, new, change, sigma) and the weak directions, in words."""
        mm = 1000.0
        lines = [f"{'marker':<10} {'robot':<8} {'old (m)':<28} {'new (m)':<28} {'change (mm)':<24} "
                 f"{'sigma (mm)':<20}"]
        f3 = lambda v, k=1.0, d=4: "[" + ", ".join(f"{x * k:+.{d}f}" for x in v) + "]"  # noqa: E731
        for n, m in self.markers.items():
            lines.append(f"{n:<10} {m.robot:<8} {f3(m.old):<28} {f3(m.new):<28} {f3(m.change, mm, 1):<24} "
                         f"{f3(m.sigma, mm, 1).replace('+', ''):<20}")
        for n, m in self.markers.items():
            if m.rotation_change_deg is not None:
                lines.append(f"{n:<10} tag rotation changed by {m.rotation_change_deg:.2f} deg, sigma "
                             + f3(np.degrees(m.rotation_sigma), 1.0, 2).replace("+", "") + " deg")
        for n in self.unobserved:
            lines.append(f"{n:<10} never observed: not calibrated, position unchanged")
        lines.append(f"{self.frames_used} of {self.frames_total} frames, {self.observations_used} observations, "
                     f"reprojection RMS {self.reprojection_rms_px:.2f} px; scale held by "
                     + ", ".join(f"|{a}-{b}| = {d:g} m" for a, b, d in self.scale)
                     + f"; {self._noise_words()}"
                     + ("" if self.prior_sigma is None else f" and the given positions good to {self.prior_sigma:g} m"))
        fitted = [o for o in self.outliers if o.get("residual_px") is not None]
        if fitted:
            lines.append(f"{len(fitted)} observations down-weighted as outliers (largest "
                         f"{max(o['residual_px'] for o in fitted):.1f} px)")
        if len(fitted) < len(self.outliers):
            lines.append(f"{len(self.outliers) - len(fitted)} observations set aside: their pixels lie outside what "
                         "their camera's lens images")
        for w in self.weak_directions:
            if w.held:
                lines.append(f"not determined by the log: {w.description}. {w.advice}")
            else:
                lines.append(f"weakly determined by the log ({w.sigma_m * mm:.1f} mm, 1 sigma): {w.description}. "
                             f"{w.advice}")
        if not self.weak_directions:
            lines.append("every marker coordinate is well determined")
        return "\n".join(lines)


# ---------------------------------------------------------------------------
# input
# ---------------------------------------------------------------------------


def parse_scale(spec: Any) -> list[tuple[str, str, float]]:
    """Scale constraints from ``"A:B=D"`` strings, ``(A, B, D)`` tuples, a
    mapping ``{(A, B): D}`` or a list of those; ``None`` gives ``[]``."""
    if spec is None:
        return []
    if isinstance(spec, Mapping):
        items: list[Any] = [(k[0], k[1], v) for k, v in spec.items()]
    elif isinstance(spec, (str, tuple)):
        items = [spec]
    else:
        items = list(spec)
    out = []
    for it in items:
        if isinstance(it, str):
            m = re.fullmatch(r"\s*([^:=\s]+)\s*:\s*([^:=\s]+)\s*=\s*(\S+)\s*", it)
            if not m:
                raise InputError(f"scale {it!r}: expected A:B=D (two markers of one robot and their distance in "
                                 "metres)")
            a, b, d = m.group(1), m.group(2), m.group(3)
            try:
                d = float(d)
            except ValueError:
                raise InputError(f"scale {it!r}: distance {d!r} is not a number (metres)") from None
        elif isinstance(it, (tuple, list)) and len(it) == 3:
            a, b, d = it
        else:
            raise InputError(f"scale {it!r}: expected 'A:B=D' or (A, B, D)")
        out.append((str(a), str(b), positive_number(d, f"scale {a}:{b} distance")))
    return out


def _read_frames(log_or_frames: Any) -> list[ObservationSet]:
    if isinstance(log_or_frames, (str, Path)):
        from .io.logs import read_observation_log

        return list(read_observation_log(log_or_frames))
    if isinstance(log_or_frames, (ObservationSet, Mapping)):
        raise InputError("calibrate_markers needs a sequence of frames (an observation log), not one frame")
    out = []
    for k, f in enumerate(log_or_frames):
        out.append(ObservationSet.from_dict(f, where=f"frame {k}: observations"))
    return out


# ---------------------------------------------------------------------------
# the markers as rigid bodies
# ---------------------------------------------------------------------------


@dataclass
class _Model:
    """The rig's markers as rigid bodies, and the points a log names.

    ``bodies`` are the user's markers (rig order): a tag whose rotation the
    rig gives is a body with a rotation and its four corners ``NAME#k`` at
    fixed offsets in its own frame; a banded cylinder a body with its bands
    ``NAME#bk`` on its axis; any other marker a single point.
    ``points[name] = (body, offset)`` (offset in the body's frame) for every
    name the expanded rig (``track``'s) knows, the bodies' own names included.
    """

    rig: Rig
    expanded: Rig
    bodies: list[str]
    robot: list[str]
    centre: np.ndarray
    rotation: np.ndarray
    rotates: np.ndarray
    points: dict[str, tuple[int, np.ndarray]]

    def point_positions(self) -> dict[str, np.ndarray]:
        """Every point in its robot's frame."""
        return {n: self.centre[b] + self.rotation[b] @ o for n, (b, o) in self.points.items()}

    @property
    def rays(self) -> bool:
        """Whether observations are rays (robots with several cameras or any lens, :mod:`mutloc.core.rays`)
        rather than pixels of one pinhole camera per robot."""
        return not self.rig.central_pinhole

    def camera_index(self, key: str) -> int:
        """The row of the camera an observation key names in :meth:`Rig.observer_keys` (a robot's own
        name for its one camera)."""
        rname, cname = self.rig.observer(key)
        return self.rig.observer_keys().index(self.rig.robots[rname].observer_key(cname))


def _model(rig: Rig) -> _Model:
    from .detect.tags import tag_rotation
    from .track.frames import expanded_rig

    expanded = expanded_rig(rig)
    bodies, robots, centres, rots, rotates = [], [], [], [], []
    for r, robot in rig.robots.items():
        for n, m in robot.markers.items():
            if (m.extra.get("tag_of") or m.extra.get("cylinder_of")) in robot.markers:
                continue  # a derived point saved in the rig: its parent is the body
            R = tag_rotation(m) if m.kind == MarkerKind.TAG else None
            bodies.append(n)
            robots.append(r)
            centres.append(m.position)
            rots.append(np.eye(3) if R is None else R)
            rotates.append(R is not None)
    index = {n: i for i, n in enumerate(bodies)}
    points: dict[str, tuple[int, np.ndarray]] = {}
    for robot in expanded.robots.values():
        for n, m in robot.markers.items():
            b = index.get(n, index.get(m.extra.get("tag_of") or m.extra.get("cylinder_of") or n))
            if b is not None:
                points[n] = (b, rots[b].T @ (m.position - centres[b]))
    return _Model(rig, expanded, bodies, robots, np.array(centres, float).reshape(-1, 3),
                  np.array(rots, float).reshape(-1, 3, 3), np.array(rotates, bool), points)


def _moved_rig(model: _Model, names: list[str], centres: np.ndarray, rotations: np.ndarray) -> dict[str, Any]:
    """The user's rig (rig-file form, the user's keys kept) with bodies
    ``names`` at new centres and, for tags, rotations."""
    out = model.rig.to_dict()
    for j, n in enumerate(names):
        b = model.bodies.index(n)
        spec = out["robots"][model.robot[b]]["markers"][n]
        spec["position"] = np.asarray(centres[j], float).tolist()
        if model.rotates[b]:
            spec["tag"] = dict(spec["tag"], rotation=so3_log(rotations[j]).tolist())
    return out


# ---------------------------------------------------------------------------
# initial poses: every frame on its own
# ---------------------------------------------------------------------------


@dataclass
class _Group:
    frame: int
    anchor: str
    members: list[str]           # slots: members other than the anchor, in rig order
    poses: dict[str, Pose]       # T_anchor_member


def _frame_groups(rig: Rig, obs: ObservationSet, frame: int, order: list[str], pixel_sigma: float
                  ) -> tuple[list[_Group], str | None]:
    """The frame's robots tied together by their observations, each set with
    its poses relative to its first robot; and why nothing was, if so.
    Every pair with enough observations is solved on its own (the pair
    solver's consistency search sets wrong detections aside), and the pairs
    are chained, those with the most observations first."""
    counts: dict[tuple[str, str], int] = {}
    for observer, m in zip(obs.observer, obs.marker):
        o, w = rig.observer(observer)[0], rig.owner(m)
        key = (o, w) if order.index(o) < order.index(w) else (w, o)
        counts[key] = counts.get(key, 0) + 1
    from .api import localize

    why = None
    edges: dict[str, dict[str, Pose]] = {}
    for (a, b), n in sorted(counts.items(), key=lambda kv: -kv[1]):
        if n < MIN_PAIR_OBSERVATIONS:
            why = why or f"{a}-{b}: {n} observations (at least {MIN_PAIR_OBSERVATIONS} needed)"
            continue
        try:
            # the rig is only approximate here: a loose noise, so that the
            # pair's own consistency search sets aside wrong detections, not
            # the rig's error
            est = localize(rig, obs, source=b, target=a, pixel_sigma=max(pixel_sigma, START_SIGMA_PX))
        except InconsistentObservationsError as exc:
            # no consistent subset (four observations leave none to spare):
            # the best attempt is the start, the adjustment judges its observations
            est = exc.estimate
            if est is None:
                why = why or f"{a}-{b}: {exc}"
                continue
        except MutlocError as exc:
            why = why or f"{a}-{b}: {exc}"
            continue
        edges.setdefault(a, {})[b] = est.pose              # T_ab
        edges.setdefault(b, {})[a] = est.pose.inverse()    # T_ba
    groups = []
    seen: set[str] = set()
    for root in order:
        if root in seen or root not in edges:
            continue
        poses = {root: Pose.identity()}
        queue = [root]
        while queue:
            a = queue.pop(0)
            for b, T_ab in edges[a].items():
                if b not in poses:
                    poses[b] = poses[a] @ T_ab
                    queue.append(b)
        seen |= set(poses)
        members = [r for r in order if r in poses and r != root]
        groups.append(_Group(frame, root, members, poses))
    return groups, (None if groups else (why or "no observations"))


def _start_residuals(rig: Rig, positions: dict[str, np.ndarray], grp: _Group, obs: ObservationSet,
                     rows: list[int]) -> np.ndarray:
    """Pixel residual lengths of observations ``rows`` of ``obs`` at the
    group's start, through the observing camera's mount and lens; inf where
    the start puts the marker behind its camera (outside its lens's field)."""
    out = np.full(len(rows), np.inf)
    for k, i in enumerate(rows):
        key, m = obs.observer[i], obs.marker[i]
        mount = rig.mount(key)
        X = (grp.poses[rig.observer(key)[0]].inverse() @ grp.poses[rig.owner(m)]).apply(positions[m])
        X = mount.pose.inverse().apply(X)
        if X[2] > 1e-6 or mount.camera.model != "pinhole":
            uv = mount.camera.project(X)
            if np.all(np.isfinite(uv)):
                out[k] = float(np.linalg.norm(uv - obs.uv[i]))
    return out


# ---------------------------------------------------------------------------
# the calibration
# ---------------------------------------------------------------------------


def calibrate_markers(rig: Any, log_or_frames: Any, scale: Any = None, pixel_sigma: float = 1.0, *,
                      prior_sigma: float | None = None, confidence: float = DEFAULT_CONFIDENCE,
                      huber: float = HUBER_K, max_iter: int = 100,
                      weak_sigma: float | None = WEAK_PRIOR_SIGMA_M, measure_noise: bool = False
                      ) -> CalibrationResult:
    """Re-estimate every observed marker's position from a sequence of mutual
    observations (SPEC "Marker calibration").

    ``log_or_frames``: an observation log's path (JSON Lines, e.g. what
    ``track --observations-out`` writes) or a sequence of frames
    (ObservationSets or the SPEC's observation dicts), any number of robots,
    observers keyed ``ROBOT`` or, for robots with several cameras (any lens),
    ``ROBOT/CAMERA``: each observation is then a ray through its own
    camera's lens and mount (:mod:`mutloc.core.rays`), its residual that
    camera's pixels to first order, the markers placed in the robots' body
    frames, and the rig's cameras kept as given; a pixel no ray leaves
    (outside what its lens images) is set aside and listed in ``outliers``
    (``"at": "lens"``).  Markers of unknown identity are not used.  Every
    marker kind: a tag whose rotation the rig gives is calibrated as a rigid
    body (centre and rotation) from its corners ``NAME#0..3``, a banded
    cylinder as its axis from its bands ``NAME#bK``, a ball as a point.
    ``scale``: distances held fixed (``"A:B=D"`` strings or ``(A, B, D)``;
    markers A and B of one robot, centres); default the two markers of the rig's first robot
    farthest apart, at their given distance.  ``pixel_sigma`` is the
    stated detection noise; observations whose residual
    fails the chi-square test (family-wise at ``confidence`` over the log)
    are reported as outliers and left out of a second fit (a Huber loss at
    ``huber`` sigma bounds their pull in the first); frames that cannot be
    placed are named in ``skipped_frames``.  Raises UnobservableMarkersError
    when the sequence cannot determine the markers.

    ``position_sigma`` (and a tag's ``rotation_sigma``) are for the stated
    detection noise ``pixel_sigma``.  With ``measure_noise`` they are for
    the noise the fit's residuals show instead (``measured_pixel_sigma``,
    per image axis; below ``pixel_sigma``, its upper two-sigma bound), as a
    bundle adjuster reports them, once the log has :data:`NOISE_MIN_DOF`
    degrees of freedom; the priors below are weighed against the pixels
    with it too.  The residuals' noise is reported either way.

    ``prior_sigma`` (metres, 1 sigma per axis; default None: the log alone)
    says how well the given positions were measured: they then count as a
    measurement, and the combinations the log determines only weakly stay
    near them instead of drifting (``position_sigma`` includes it; the weak
    directions and the refusal are judged on the log alone).  Without it,
    the combinations the log determines worse than ``weak_sigma`` (two
    upright robots leave some; default 1 cm, what a tape measure gives) are
    taken from the given rig, good to ``weak_sigma`` along them (the log's
    weak say along them is not fused in: it rests on pixel changes where
    the detectors' small systematic errors decide it), and reported as weak
    with the log's own sigma; ``weak_sigma=None``: the log alone everywhere.  A log that leaves more than half the unknowns
    undetermined (sigma above :data:`MAX_SIGMA_M`) is refused.
    """
    from .api import load_rig

    rig = load_rig(rig)
    pixel_sigma = positive_number(pixel_sigma, "pixel_sigma")
    huber = positive_number(huber, "huber")
    if prior_sigma is not None:
        prior_sigma = positive_number(prior_sigma, "prior_sigma")
    order = list(rig.robots)
    model = _model(rig)
    frames = _read_frames(log_or_frames)
    named = _check_scale(model, parse_scale(scale))
    frames = _checked(model, frames)
    frames, rays, unimaged = _frame_rays(model, frames)
    data = _collect(model, frames, rays, order, pixel_sigma)

    # Unknowns: the observed markers (bodies), in rig order.
    observed = {model.points[r[4]][0] for r in data.rows}
    names = [n for b, n in enumerate(model.bodies) if b in observed]
    unobserved = [n for b, n in enumerate(model.bodies) if b not in observed]
    bindex = {n: i for i, n in enumerate(names)}
    named = named or [_default_scale(model, order, {model.bodies[b] for b in observed})]
    for a, b, _ in named:
        for n in (a, b):
            if n not in bindex:
                raise UnobservableMarkersError(f"scale {a}:{b}: marker {n!r} is never observed in the log, so its "
                                               "distance cannot hold the scale")
    constraints = tuple((bindex[a], bindex[b], d) for a, b, d in named)
    body = [model.bodies.index(n) for n in names]
    old, old_rot = model.centre[body].copy(), model.rotation[body].copy()
    if prior_sigma is not None:
        prior = (old, (pixel_sigma / prior_sigma) ** 2, None)
    elif weak_sigma is not None:
        # first everything near the given rig (a weakly determined log would
        # otherwise let the start wander), then only the weak combinations
        weak_sigma = positive_number(weak_sigma, "weak_sigma")
        prior = (old, (pixel_sigma / weak_sigma) ** 2, None)
    else:
        prior = (None, 0.0, None)
    args = (model, order, bindex, constraints, pixel_sigma, huber, max_iter, confidence)
    fit = _fit(data, prior, old, old_rot, *args)
    if data.skipped or data.gross or fit.outliers:
        # Frames the given rig could not place, or placed wrongly: every frame
        # again from the calibrated markers (each on its own, as before).
        better = _model(load_rig(_moved_rig(model, names, fit.adjustment.markers, fit.adjustment.rotations)))
        again = _collect(better, frames, rays, order, pixel_sigma, required=False)
        if again.groups and {better.points[r[4]][0] for r in again.rows} >= observed:
            data = again
            fit = _fit(data, prior, fit.adjustment.markers, fit.adjustment.rotations, *args)
    marker_robot = [model.robot[b] for b in body]
    n_par = len(fit.adjustment.information)
    # The noise behind the sigmas (``noise``: the stated one, or with
    # measure_noise the residuals') and the noise the held combinations are
    # judged at (``judge``: always the residuals', :func:`_hold_noise`),
    # measured from the residuals; the fit again while what drives it moves.
    noise, judge, measured = pixel_sigma, pixel_sigma, None
    held: tuple | None = None
    drives = None
    motion = _motion_summary(fit.groups, fit.adjustment, order, rig)
    for round_ in range(_NOISE_ROUNDS):
        # the held combinations are not estimated: no degrees of freedom spent on them
        dof = fit.dof + (0 if held is None else len(held[0]))
        measured = _measured_noise(fit.adjustment, dof)
        judged = _hold_noise(measured, dof, pixel_sigma)
        target = judged if measure_noise else pixel_sigma
        # the prior's weight follows the reported noise; the held combinations the judged one
        now = target if prior_sigma is not None else judged
        if round_ > 0 and abs(math.log(now / drives)) < math.log(_NOISE_SETTLED):
            break
        noise, judge, drives = target, judged, now
        adj = fit.adjustment
        _, C = constraint_jacobian(adj.markers, constraints, n_par)
        if prior_sigma is not None:
            if round_ == 0 and abs(math.log(noise / pixel_sigma)) < math.log(_NOISE_SETTLED):
                break  # the first fit's weights already
            prior = (old, (noise / prior_sigma) ** 2, None)
        else:
            if round_ == 0:
                # what the log cannot determine at all: judged at the stated noise
                free = n_par - len(constraints)
                V, sig_v = _undetermined(adj, C, pixel_sigma, len(names), MAX_SIGMA_M)
                if len(V) > free // 2 or (weak_sigma is None and len(V)):
                    _refuse_undetermined(adj, C, names, marker_robot, motion, pixel_sigma, fit.frames_used)
            if weak_sigma is None:
                break  # the log alone: no weight depends on the noise
            # Which combinations the log determines worse than the given rig
            # is judged at the noise the residuals show, not the stated one:
            # a stated noise above the detections' (the default 1 px against
            # rendered or sub-pixel detections) would hold combinations the
            # log determines well at the given rig's error, and leave the
            # poses' rotations off by it.
            V, sig_v = _undetermined(adj, C, judge, len(names), weak_sigma)
            held = (V, sig_v) if len(V) else None
            # held: taken from the given rig (stiffly), not fused with the
            # log's weak say along them (systematic detection errors, a
            # fraction of a pixel, decide what the log says there); the
            # covariance adds the given rig's own error back
            prior = (old, HOLD_STIFFNESS * (judge / weak_sigma) ** 2, _orthonormal(V)) if len(V) \
                else (None, 0.0, None)
        outliers, dropped = fit.outliers, fit.dropped
        fit = _fit(fit.data, prior, adj.markers, adj.rotations, *args)
        fit.outliers, fit.dropped = outliers + fit.outliers, dropped + fit.dropped
    adj = fit.adjustment
    _, C = constraint_jacobian(adj.markers, constraints, n_par)
    cov_post, _ = adj.marker_covariance(C, noise, prior_sigma=weak_sigma if held is not None else None)
    if held is not None:
        # the log's own sigma along the held combinations, for the reported noise
        held = (held[0], held[1] * (noise / judge))
    weak = _weak_directions(adj, C, names, marker_robot, motion, noise, fit.frames_used, held, weak_sigma)
    nb = 3 * len(names)
    sigma = np.sqrt(np.clip(np.diag(cov_post)[:nb], 0.0, None)).reshape(-1, 3)
    rot_sigma = np.sqrt(np.clip(np.diag(cov_post)[nb:], 0.0, None)).reshape(-1, 3)
    markers: dict[str, MarkerCalibration] = {}
    k = 0
    for j, n in enumerate(names):
        m = MarkerCalibration(n, marker_robot[j], old[j], adj.markers[j].copy(), sigma[j])
        if model.rotates[body[j]]:
            m.old_rotation, m.new_rotation = so3_log(old_rot[j]), so3_log(adj.rotations[j])
            m.rotation_sigma = rot_sigma[k]
            k += 1
        markers[n] = m
    new_rig = _moved_rig(model, names, adj.markers, adj.rotations)
    for n, m in markers.items():
        spec = new_rig["robots"][m.robot]["markers"][n]
        spec["position_sigma"] = m.sigma.tolist()
        if m.rotation_sigma is not None:
            spec["tag"]["rotation_sigma"] = m.rotation_sigma.tolist()
    for n in unobserved:
        # A sigma from an earlier calibration no longer describes this rig's position.
        spec = new_rig["robots"][model.robot[model.bodies.index(n)]]["markers"][n]
        spec.pop("position_sigma", None)
        if isinstance(spec.get("tag"), dict):
            spec["tag"].pop("rotation_sigma", None)
    poses = [{"frame": g.frame, "reference": g.anchor,
              "poses": {r: Pose(adj.R[gi, s].copy(), adj.t[gi, s].copy()) for s, r in enumerate(g.members)}}
             for gi, g in enumerate(fit.groups)]
    skipped = sorted(data.skipped + fit.dropped, key=lambda d: d["frame"])
    return CalibrationResult(
        rig=new_rig, markers=markers, weak_directions=weak, scale=list(named), pixel_sigma=pixel_sigma,
        measured_pixel_sigma=measured, sigma_noise_px=noise,
        covariance=cov_post[:nb, :nb], covariance_markers=names, prior_sigma=prior_sigma, frames_total=len(frames),
        frames_used=fit.frames_used, observations_used=len(fit.rows),
        reprojection_rms_px=float(np.sqrt(np.mean(np.sum(adj.residuals**2, axis=1)))), chi2=adj.chi2,
        dof=fit.dof, iterations=adj.iterations, converged=adj.converged, outliers=unimaged + data.gross + fit.outliers,
        unobserved=unobserved, skipped_frames=skipped, poses=poses)


def _check_scale(model: _Model, named: list[tuple[str, str, float]]) -> list[tuple[str, str, float]]:
    """The held distances, each between two known markers of one robot."""
    rig = model.rig
    for a, b, _ in named:
        for n in (a, b):
            if n not in model.bodies:
                if n in model.points:
                    raise InputError(f"scale {a}:{b}: {n!r} is a point of marker "
                                     f"{model.bodies[model.points[n][0]]!r}; a held distance is between the centres "
                                     "of two markers (their names in the rig)")
                raise UnknownMarkerError(f"scale {a}:{b}: unknown marker {n!r} (rig has {', '.join(model.bodies)})")
        if rig.owner(a) != rig.owner(b):
            raise InputError(f"scale {a}:{b}: markers of different robots ({rig.owner(a)!r}, {rig.owner(b)!r}); "
                             "a held distance is between two markers of one robot")
        if a == b:
            raise InputError(f"scale {a}:{b}: a marker's distance to itself")
    return named


def _checked(model: _Model, frames: list[ObservationSet]) -> list[ObservationSet]:
    """The frames' best candidates of known identity, checked against the expanded rig."""
    out = []
    for k, frame in enumerate(frames):
        obs = frame.best()
        if any(m is None for m in obs.marker):
            obs = obs.take(np.array([m is not None for m in obs.marker]))
        try:
            obs.check(model.expanded)
        except MutlocError as exc:
            raise type(exc)(f"{_where(k, obs)}: {exc}") from None
        out.append(obs)
    return out


def _frame_rays(model: _Model, frames: list[ObservationSet]
                ) -> tuple[list[ObservationSet], list[np.ndarray] | None, list[dict[str, Any]]]:
    """When the rig is not one pinhole camera per robot: the frames, each
    frame's observations as rays of their observers' robot frames
    (:func:`mutloc.core.rays.ray_frames`, (n, 4, 3) per frame), and the
    observations set aside because no ray leaves their pixel (outside what
    the lens images, e.g. past a fisheye polynomial's fold: a stray
    detection near the rim), named.  Else the frames unchanged, None, []."""
    if not model.rays:
        return frames, None, []
    from .core.rays import ray_frames

    rig = model.expanded
    out_frames, out_rays, aside = [], [], []
    for k, obs in enumerate(frames):
        F = np.empty((len(obs), 4, 3))
        ok = np.ones(len(obs), dtype=bool)
        for key in dict.fromkeys(obs.observer):
            ix = np.array([i for i, o in enumerate(obs.observer) if o == key])
            mount = rig.mount(key)
            b = np.asarray(mount.camera.pixels_to_bearings(obs.uv[ix]), float).reshape(-1, 3)
            good = np.all(np.isfinite(b), axis=1)
            ok[ix[~good]] = False
            if good.any():
                F[ix[good]] = ray_frames(mount, obs.uv[ix[good]])[1]
        for i in np.flatnonzero(~ok):
            aside.append({"frame": k, "observer": obs.observer[i], "marker": obs.marker[i], "residual_px": None,
                          "at": "lens"})
        if not ok.all():
            obs, F = obs.take(ok), F[ok]
        out_frames.append(obs)
        out_rays.append(np.ascontiguousarray(F))
    return out_frames, out_rays, aside


def _where(k: int, obs: ObservationSet) -> str:
    return f"frame {k}" + ("" if len(obs) == 0 or np.all(np.isnan(obs.time)) else f" (time {obs.time[0]:g})")


@dataclass
class _Collected:
    groups: list[_Group]
    rows: list[tuple]                     # group, observer slot, owner slot, camera, point, u, v[, ray frame]
    row_info: list[tuple[int, str, str]]  # frame, observer, marker
    skipped: list[dict[str, Any]]
    gross: list[dict[str, Any]] = field(default_factory=list)  # set aside at the start


def _collect(model: _Model, frames: list[ObservationSet], rays: list[np.ndarray] | None, order: list[str],
             pixel_sigma: float, required: bool = True) -> _Collected:
    """Every frame on its own: its groups with their initial poses, and the
    observation rows (with their ray frames, ``rays``, when given).  An
    observation the start puts behind the camera that sees it is set aside;
    a group left with fewer than three observations of a robot, and a frame
    nothing places, is skipped and named."""
    rig = model.expanded
    positions = model.point_positions()
    out = _Collected([], [], [], [], [])
    for k, obs in enumerate(frames):
        fg, why = _frame_groups(rig, obs, k, order, pixel_sigma)
        robot = [rig.observer(key)[0] for key in obs.observer]
        placed = False
        for grp in fg:
            slot = {r: i for i, r in enumerate(grp.members)}
            slot[grp.anchor] = -1
            idx = [i for i, m in enumerate(obs.marker) if robot[i] in slot and rig.owner(m) in slot]
            res = _start_residuals(rig, positions, grp, obs, idx)
            for i, e in zip(idx, res):
                if START_GATE_PX < e < math.inf:
                    out.gross.append({"frame": k, "observer": obs.observer[i], "marker": obs.marker[i],
                                      "residual_px": float(e), "at": "start"})
            idx = [i for i, e in zip(idx, res) if e <= START_GATE_PX]
            count: dict[str, int] = {}
            for i in idx:
                for r in (robot[i], rig.owner(obs.marker[i])):
                    count[r] = count.get(r, 0) + 1
            if any(count.get(r, 0) < 3 for r in slot):
                why = why or "the frame's poses put markers behind the cameras that see them"
                continue
            gi = len(out.groups)
            out.groups.append(grp)
            placed = True
            for i in idx:
                o, m = obs.observer[i], obs.marker[i]
                u, v = obs.uv[i].tolist()
                row = (gi, slot[robot[i]], slot[rig.owner(m)], model.camera_index(o), m, u, v)
                out.rows.append(row if rays is None else row + (rays[k][i],))
                out.row_info.append((k, o, m))
        if not placed:
            out.skipped.append({"frame": k, "reason": why or "no observations"})
    if not out.groups and required:
        raise UnobservableMarkersError(
            f"no frame of the {len(frames)} could be localized with the given rig"
            + (f" (frame 0: {out.skipped[0]['reason']})" if out.skipped else "")
            + ": the log needs frames where two robots see at least four of each other's markers")
    return out


@dataclass
class _Fit:
    adjustment: Any
    groups: list[_Group]
    rows: list[tuple]
    outliers: list[dict[str, Any]]
    frames_used: int
    dof: int
    dropped: list[dict[str, Any]] = field(default_factory=list)
    data: _Collected | None = None   # the groups (poses at the optimum) and rows it used


def _fit(data: _Collected, prior: tuple, start: np.ndarray, start_rot: np.ndarray, model: _Model, order: list[str],
         bindex: dict[str, int], constraints: tuple, pixel_sigma: float, huber: float, max_iter: int,
         confidence: float) -> _Fit:
    """The bundle adjustment; observations failing their own chi-square test
    are reported and left out of a second fit (the Huber loss bounds their
    pull but does not remove it).  The test is family-wise at
    ``confidence``: a log without a stray detection passes whole with that
    probability, however long it is.  A frame left without enough
    observations is dropped and named."""
    groups, rows, info = data.groups, data.rows, data.row_info
    problem, R0, t0 = _problem(model, groups, rows, bindex, constraints, prior)
    depth_ok = start_depths(problem, start, R0, t0, start_rot) > 0
    if not depth_ok.all():
        groups, rows, info = _without(groups, rows, depth_ok, info)
        if not groups:
            raise UnobservableMarkersError("no frame is left once the observations the start puts behind their "
                                           "cameras are set aside")
        problem, R0, t0 = _problem(model, groups, rows, bindex, constraints, prior)
    frames_used = len({g.frame for g in groups})
    if problem.dof < 0:
        raise UnobservableMarkersError(
            f"too few frames: {frames_used} usable frame{'s' if frames_used != 1 else ''} give "
            f"{2 * len(rows)} measurements for {problem.n_pose_parameters} pose and "
            f"{problem.n_parameters - len(constraints)} marker unknowns; record more frames while the robots move "
            "(different distances, turning in place while facing each other, rolling)")
    adj = adjust(problem, start, R0, t0, pixel_sigma=pixel_sigma, huber=huber, max_iter=max_iter,
                 rotations0=start_rot)
    gate = chi2_quantile(1.0 - (1.0 - confidence) / len(rows), 2) * pixel_sigma**2 if confidence < 1.0 else math.inf
    e2 = np.sum(adj.residuals**2, axis=1)
    outliers = [{"frame": info[i][0], "observer": info[i][1], "marker": info[i][2],
                 "residual_px": float(np.sqrt(e2[i]))} for i in np.flatnonzero(e2 > gate)]
    dropped: list[dict[str, Any]] = []
    if outliers:
        for gi, grp in enumerate(groups):
            for s, r in enumerate(grp.members):
                grp.poses[r] = Pose(adj.R[gi, s].copy(), adj.t[gi, s].copy())
        kept_frames = {g.frame for g in groups}
        groups, rows, info = _without(groups, rows, e2 <= gate, info)
        if not groups:
            raise UnobservableMarkersError("no frame is left once the observations that fail their chi-square test "
                                           f"at {pixel_sigma:g} px are set aside: is --pixel-sigma right?")
        left = {g.frame for g in groups}
        dropped = [{"frame": f, "reason": "too few observations left once its outliers are set aside"}
                   for f in sorted(kept_frames - left)]
        problem, R0, t0 = _problem(model, groups, rows, bindex, constraints, prior)
        frames_used = len(left)
        adj = adjust(problem, adj.markers, R0, t0, pixel_sigma=pixel_sigma, huber=huber, max_iter=max_iter,
                     rotations0=adj.rotations)
    for gi, grp in enumerate(groups):
        for s, r in enumerate(grp.members):
            grp.poses[r] = Pose(adj.R[gi, s].copy(), adj.t[gi, s].copy())
    return _Fit(adj, groups, rows, outliers, frames_used, problem.dof, dropped,
                _Collected(groups, rows, info, data.skipped, data.gross))


def _measured_noise(adj: Any, dof: int) -> float | None:
    """The detection noise (px, per image axis) the residuals show:
    ``sqrt(sum r^2 / dof)``; None without degrees of freedom."""
    if dof <= 0:
        return None
    return float(np.sqrt(np.sum(adj.residuals**2) / dof))


def _sigma_noise(measured: float | None, dof: int, stated: float) -> float:
    """The noise behind the reported sigmas: the measured one once the log
    has :data:`NOISE_MIN_DOF` degrees of freedom (below the stated noise its
    upper two-sigma bound, never below :data:`NOISE_FLOOR` of the stated),
    else the stated one."""
    if measured is None or dof < NOISE_MIN_DOF:
        return stated
    if measured >= stated:
        return measured
    upper = measured * math.sqrt(1.0 + 2.0 * math.sqrt(2.0 / dof))
    return max(min(upper, stated), NOISE_FLOOR * stated)


def _hold_noise(measured: float | None, dof: int, stated: float) -> float:
    """The noise (px) at which the combinations the log determines worse than
    the given rig are judged (and the held ones weighed against the pixels):
    the residuals' measured noise, as :func:`_sigma_noise` bounds it, whether
    or not the reported sigmas are for it."""
    return _sigma_noise(measured, dof, stated)


def _undetermined(adj: Any, C: np.ndarray, pixel_sigma: float, n_bodies: int,
                  limit: float) -> tuple[np.ndarray, np.ndarray]:
    """The combinations of the centres the log alone determines no better
    than ``limit`` (metres, 1 sigma) or not at all: unit rows (h, 3B) and
    the log's own sigma along each (inf: none at all)."""
    Z = null_space(C, C.shape[1])
    N = Z.T @ adj.data_information() @ Z
    w, U = np.linalg.eigh(0.5 * (N + N.T))
    singular = w <= SINGULAR_RATIO * max(w[-1], 1e-300)
    bad = singular | (pixel_sigma**2 / np.maximum(w, 1e-300) > limit**2)
    V = (Z @ U[:, bad])[: 3 * n_bodies].T
    norm = np.linalg.norm(V, axis=1)
    keep = norm > 0.5  # mostly centres (a tag's rotation alone is never this weak)
    sig = np.where(singular[bad], np.inf, pixel_sigma / np.sqrt(np.maximum(w[bad], 1e-300)))
    return V[keep] / norm[keep, None], sig[keep]


def _orthonormal(V: np.ndarray) -> np.ndarray:
    u, s, _ = np.linalg.svd(V.T, full_matrices=False)
    return u[:, s > 1e-6].T


def _refuse_undetermined(adj: Any, C: np.ndarray, names: list[str], marker_robot: list[str], motion: "_Motion",
                         pixel_sigma: float, frames_used: int) -> None:
    """UnobservableMarkersError naming the combination the log determines least."""
    Z = null_space(C, C.shape[1])
    N = Z.T @ adj.data_information() @ Z
    w, U = np.linalg.eigh(0.5 * (N + N.T))
    v = (Z @ U[:, 0])[: 3 * len(names)]
    if w[0] <= SINGULAR_RATIO * max(w[-1], 1e-300):
        raise UnobservableMarkersError(
            f"the log cannot determine the markers: {_describe(v, names, marker_robot, motion.bodies)} changes no "
            "pixel "
            f"({frames_used} usable frames{motion.note}). {_advice(v, motion, marker_robot)}")
    raise UnobservableMarkersError(
        f"the log cannot determine the markers: {_describe(v, names, marker_robot, motion.bodies)} is known only to "
        f"{pixel_sigma / math.sqrt(w[0]) * 1000:.0f} mm (1 sigma at {pixel_sigma:g} px; {frames_used} usable "
        f"frames{motion.note}). {_advice(v, motion, marker_robot)}")


def _weak_directions(adj: Any, C: np.ndarray, names: list[str], marker_robot: list[str], motion: "_Motion",
                     pixel_sigma: float, frames_used: int, held: tuple | None,
                     weak_sigma: float | None) -> list[WeakDirection]:
    """The combinations of marker centres the log alone determines weakly,
    weakest first; ``held`` (directions, the log's sigmas): those held near
    the given rig, listed first."""
    nb = 3 * len(names)
    cov_all, _ = adj.marker_covariance(C, pixel_sigma, data_only=held is None, prior_sigma=weak_sigma)
    if held is not None:
        # The log's own sigma of everything but the held combinations.
        Q = null_space(held[0], nb)
        cov = Q @ (Q.T @ cov_all[:nb, :nb] @ Q) @ Q.T
    else:
        cov = cov_all[:nb, :nb]
    w, V = np.linalg.eigh(0.5 * (cov + cov.T))
    w = np.clip(w, 0.0, None)[::-1]
    V = V[:, ::-1]
    sig = np.sqrt(w)
    free = sig[: nb - C.shape[0] - (0 if held is None else len(held[0]))]
    med = float(np.median(free)) if len(free) else 0.0
    weak = []
    if held is not None:
        for v, s in zip(*held):
            s = float(s)
            weak.append(WeakDirection(
                s, _describe(v, names, marker_robot, motion.bodies)
                + (f" (the log alone: {s * 1000:.0f} mm, 1 sigma)" if math.isfinite(s) else " (the log alone: not at all)")
                + f" is taken from the given rig, good to {weak_sigma * 1000:g} mm along it",
                _advice(v, motion, marker_robot), {n: v[3 * j:3 * j + 3].tolist() for j, n in enumerate(names)},
                held=True))
    for i in range(len(free)):
        if sig[i] > WEAK_RATIO * med and sig[i] > WEAK_MIN_M:
            v = V[:, i]
            weak.append(WeakDirection(float(sig[i]), _describe(v, names, marker_robot, motion.bodies),
                                      _advice(v, motion, marker_robot),
                                      {n: v[3 * j:3 * j + 3].tolist() for j, n in enumerate(names)}))
    return weak


def _problem(model: _Model, groups: list[_Group], rows: list[tuple], bindex: dict[str, int], constraints: tuple,
             prior: tuple) -> tuple[BundleProblem, np.ndarray, np.ndarray]:
    """The adjustment's problem and its start (the groups' poses)."""
    n_slots = max(1, max(len(g.members) for g in groups))
    G = len(groups)
    slot_used = np.zeros((G, n_slots), dtype=bool)
    R0 = np.broadcast_to(np.eye(3), (G, n_slots, 3, 3)).copy()
    t0 = np.zeros((G, n_slots, 3))
    for gi, grp in enumerate(groups):
        for s, r in enumerate(grp.members):
            slot_used[gi, s] = True
            R0[gi, s] = grp.poses[r].R
            t0[gi, s] = grp.poses[r].t
    # the observed points, each of an unknown body
    pnames = sorted({r[4] for r in rows}, key=lambda n: (bindex[model.bodies[model.points[n][0]]], n))
    pindex = {n: i for i, n in enumerate(pnames)}
    body = [bindex[model.bodies[model.points[n][0]]] for n in pnames]
    rotates = np.array([bool(model.rotates[model.bodies.index(n)]) for n in bindex], dtype=bool)
    simple = not rotates.any() and all(not np.any(model.points[n][1]) for n in pnames) and body == list(range(len(body)))
    arr = np.array([(r[0], r[1], r[2], r[3]) for r in rows], dtype=np.int64).reshape(-1, 4)
    if model.rays:
        # rays: no camera matrix is used
        K, dist = np.zeros((1, 3, 3)), np.zeros((1, 8))
        frames = np.array([r[7] for r in rows], dtype=float).reshape(-1, 4, 3)
    else:
        order = list(model.rig.robots)
        K = np.ascontiguousarray(np.stack([model.rig.robots[r].camera.K for r in order]))
        dist = np.ascontiguousarray(np.stack([model.rig.robots[r].camera.dist for r in order]))
        frames = None
    problem = BundleProblem(
        group=np.ascontiguousarray(arr[:, 0]), observer_slot=np.ascontiguousarray(arr[:, 1]),
        owner_slot=np.ascontiguousarray(arr[:, 2]), camera=np.ascontiguousarray(arr[:, 3]),
        marker=np.array([pindex[r[4]] for r in rows], dtype=np.int64),
        uv=np.array([(r[5], r[6]) for r in rows], dtype=float).reshape(-1, 2),
        K=K, dist=dist, slot_used=slot_used, n_markers=len(pnames), constraints=constraints, prior=prior[0],
        prior_weight=prior[1], prior_directions=prior[2],
        point_body=None if simple else np.array(body, dtype=np.int64),
        point_offset=None if simple else np.array([model.points[n][1] for n in pnames], float).reshape(-1, 3),
        body_rotates=None if simple else rotates, frames=frames)
    return problem, R0, t0


def _without(groups: list[_Group], rows: list[tuple], keep: np.ndarray, info: list[tuple]
             ) -> tuple[list[_Group], list[tuple], list[tuple]]:
    """The groups, rows and row infos left when only rows ``keep`` are used;
    a group in which a robot keeps fewer than three observations is dropped
    whole."""
    count: dict[tuple[int, int], int] = {}
    for r, k in zip(rows, keep):
        if k:
            for s_ in (r[1], r[2]):
                count[(r[0], s_)] = count.get((r[0], s_), 0) + 1
    ok = [all(count.get((gi, s_), 0) >= 3 for s_ in range(-1, len(g.members))) for gi, g in enumerate(groups)]
    renum = {gi: k for k, gi in enumerate(gi for gi in range(len(groups)) if ok[gi])}
    sel = [i for i, (r, k) in enumerate(zip(rows, keep)) if k and ok[r[0]]]
    new_rows = [(renum[rows[i][0]],) + tuple(rows[i][1:]) for i in sel]
    return [g for gi, g in enumerate(groups) if ok[gi]], new_rows, [info[i] for i in sel]


def _default_scale(model: _Model, order: list[str], observed: set[str]) -> tuple[str, str, float]:
    """SPEC: the two markers farthest apart on the first robot, at their given distance."""
    first = order[0]
    rig = model.rig
    names = [n for n in rig.robots[first].markers if n in observed]
    if len(names) < 2:
        raise UnobservableMarkersError(
            f"the scale: robot {first!r} (the rig's first) has {len(names)} observed marker"
            f"{'s' if len(names) != 1 else ''}, and bearings never fix the scale; give a distance between two "
            "markers of one robot (--scale A:B=D)")
    best = (-1.0, "", "")
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            d = float(np.linalg.norm(rig.marker(a).position - rig.marker(b).position))
            if d > best[0]:
                best = (d, a, b)
    return best[1], best[2], best[0]


def _describe(v: np.ndarray, names: Sequence[str], marker_robot: Sequence[str],
              bodies: frozenset[str] = frozenset()) -> str:
    """A marker-space direction in words: per robot, how its markers move
    (along a camera frame's axes, or a body's, ``bodies``)."""
    v = np.asarray(v, float).reshape(-1, 3)
    total = float(np.sum(v * v))
    parts = []
    for r in dict.fromkeys(marker_robot):
        idx = [j for j, o in enumerate(marker_robot) if o == r]
        share = float(np.sum(v[idx] ** 2)) / total if total > 0 else 0.0
        if share < 0.1:
            continue
        mean = v[idx].mean(axis=0)
        if float(np.sum(mean**2)) * len(idx) >= 0.5 * float(np.sum(v[idx] ** 2)):
            k = int(np.argmax(np.abs(mean)))
            words = _BODY_AXIS_WORDS if r in bodies else _AXIS_WORDS
            parts.append(words[k][0 if mean[k] > 0 else 1].format(r=r))
        else:
            each = []
            for j in idx:
                k = int(np.argmax(np.abs(v[j])))
                each.append(f"{names[j]} {'+-'[int(v[j, k] < 0)]}{'xyz'[k]}")
            parts.append(f"moving {r}'s markers apart or around each other ({', '.join(each)})")
    if not parts:
        return "a combination of marker positions"
    return parts[0] + "".join(f" while {p}" for p in parts[1:])


@dataclass
class _Motion:
    note: str
    advice: str
    specific: bool = True
    #: The robots whose frames are bodies (x forward, y left, z up), not cameras' optical frames.
    bodies: frozenset[str] = frozenset()
    all_bodies: bool = False

    def words(self, text: str) -> str:
        """``text`` with a body's tilt for a camera's roll when every robot is a body."""
        if self.all_bodies:
            for camera_words, body_words in _ROLL_WORDS:
                text = text.replace(camera_words, body_words)
        return text


def _vertical(robot: str, bodies: frozenset[str]) -> int:
    """The axis of a robot's frame that points up (or down) on an upright robot: z of a body, y of a camera."""
    return 2 if robot in bodies else 1


_ROLL_ADVICE = ("The robots hardly roll relative to each other: roll one robot about its optical axis during the "
                "recording (or tilt it), or add a third robot that sees both")
_TURN_ADVICE = ("The robots hardly turn relative to each other: turn one robot in place further (yaw) while it faces "
                "the other, record from more distances, or add a third robot that sees both")


def _advice(v: np.ndarray, motion: _Motion, marker_robot: Sequence[str] = ()) -> str:
    """The motion that would determine direction ``v``: the log's own
    shortcoming when it has an obvious one, else by the axis ``v`` moves
    along (up and down: each marker's robot's vertical axis)."""
    if motion.specific:
        return motion.advice
    v = np.abs(np.asarray(v, float).reshape(-1, 3))
    up = np.array([_vertical(r, motion.bodies) for r in marker_robot] or [1] * len(v))
    vertical = float(v[np.arange(len(v)), up].sum())
    other = v.sum(axis=0) - np.bincount(up, weights=v[np.arange(len(v)), up], minlength=3)
    return motion.words(_ROLL_ADVICE) if vertical > other.max() else _TURN_ADVICE


def _motion_summary(groups: list[_Group], adj: Any, order: list[str], rig: Rig) -> _Motion:
    """What the log's relative poses did, and the motion that would add what is missing."""
    bodies = frozenset(r for r, robot in rig.robots.items() if robot.is_body)
    motion = _motion_words(groups, adj, bodies)
    motion.bodies, motion.all_bodies = bodies, bodies == set(rig.robots)
    motion.advice = motion.words(motion.advice)
    return motion


def _motion_words(groups: list[_Group], adj: Any, bodies: frozenset[str]) -> _Motion:
    """:func:`_motion_summary`'s finding, in a camera frame's words."""
    general = ("Roll one robot about its optical axis during the recording (or tilt it), or add a third robot "
               "that sees both")
    pair = [(gi, g) for gi, g in enumerate(groups) if len(g.members) >= 1]
    if len(pair) < 2:
        return _Motion("", "Record more frames while the robots move: different distances, turning in place "
                           "while facing each other, rolling one robot about its optical axis")
    Rs = np.array([adj.R[gi, 0] for gi, _ in pair])
    ts = np.array([adj.t[gi, 0] for gi, _ in pair])
    dR = np.einsum("nji,jk->nik", Rs, Rs[0])
    ang = np.degrees(np.arccos(np.clip((np.trace(dR, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    dt = ts - ts.mean(axis=0)
    sv = np.linalg.svd(dt, compute_uv=False) if len(dt) > 1 else np.zeros(3)
    if ang.max() < SAME_POSE_DEG and sv[0] / math.sqrt(len(dt)) < SAME_POSE_M:
        return _Motion("; every frame shows the same relative pose",
                       "Move the robots during the recording: different distances, turning in place while facing "
                       "each other, rolling one robot about its optical axis")
    if ang.max() < SAME_POSE_DEG:
        return _Motion("; the robots never turned relative to each other, they only moved",
                       "Turn in place while facing the other robot, and roll one robot about its optical axis "
                       "during the recording")
    # Relative rotations all about one axis (e.g. upright robots that only yaw)?
    axes = []
    for R in dR:
        w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
        if np.linalg.norm(w) > 2 * math.sin(math.radians(SAME_POSE_DEG)):
            axes.append(w / np.linalg.norm(w))
    if axes:
        A = np.array(axes)
        s, Vt = np.linalg.svd(A, full_matrices=False)[1:]
        if len(s) > 1 and s[1] < 0.2 * s[0]:
            axis = Vt[0] * np.sign(Vt[0][np.argmax(np.abs(Vt[0]))])
            k = int(np.argmax(np.abs(axis)))
            member = pair[0][1].members[0]
            return _Motion(f"; the relative rotations all turn about one axis, {member}'s {'xyz'[k]}", general,
                           specific=k == _vertical(member, bodies))
    return _Motion("", general, specific=False)

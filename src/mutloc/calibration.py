"""Marker self-calibration from a log of mutual observations (SPEC "Marker
calibration"): :func:`calibrate_markers`.

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

from .core.calibration import HUBER_K, BundleProblem, adjust, constraint_jacobian, null_space
from .core.consistency import DEFAULT_CONFIDENCE, chi2_quantile
from .core.observations import ObservationSet
from .core.pose import Pose
from .core.rig import Rig
from .errors import InputError, MutlocError, UnknownMarkerError, UnobservableMarkersError, positive_number

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
#: A combination whose sigma is above this many times the median one (and
#: above :data:`WEAK_MIN_M`) is reported as weakly determined.
WEAK_RATIO = 4.0
WEAK_MIN_M = 0.003
# Frames this close in relative pose count as one pose (degree, metre).
SAME_POSE_DEG = 3.0
SAME_POSE_M = 0.01

_AXIS_WORDS = (("moving {r}'s markers right (+x)", "moving {r}'s markers left (-x)"),
               ("lowering {r}'s markers (+y)", "raising {r}'s markers (-y)"),
               ("moving {r}'s markers forward (+z)", "moving {r}'s markers back (-z)"))


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

    @property
    def change(self) -> np.ndarray:
        return self.new - self.old

    def to_dict(self) -> dict[str, Any]:
        return {"robot": self.robot, "old": self.old.tolist(), "new": self.new.tolist(),
                "change": self.change.tolist(), "change_m": float(np.linalg.norm(self.change)),
                "position_sigma": self.sigma.tolist()}


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

    def to_dict(self) -> dict[str, Any]:
        return {"sigma_m": self.sigma_m, "description": self.description, "advice": self.advice,
                "shifts": self.shifts}


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
            "pixel_sigma": self.pixel_sigma, "prior_sigma": self.prior_sigma,
            "frames_total": self.frames_total, "frames_used": self.frames_used,
            "observations_used": self.observations_used, "reprojection_rms_px": self.reprojection_rms_px,
            "chi2": self.chi2, "dof": self.dof, "iterations": self.iterations, "converged": self.converged,
            "outliers": self.outliers, "unobserved": self.unobserved, "skipped_frames": self.skipped_frames,
        }

    def summary(self) -> str:
        """The per-marker table (old, new, change, sigma) and the weak directions, in words."""
        mm = 1000.0
        lines = [f"{'marker':<10} {'robot':<8} {'old (m)':<28} {'new (m)':<28} {'change (mm)':<24} "
                 f"{'sigma (mm)':<20}"]
        f3 = lambda v, k=1.0, d=4: "[" + ", ".join(f"{x * k:+.{d}f}" for x in v) + "]"  # noqa: E731
        for n, m in self.markers.items():
            lines.append(f"{n:<10} {m.robot:<8} {f3(m.old):<28} {f3(m.new):<28} {f3(m.change, mm, 1):<24} "
                         f"{f3(m.sigma, mm, 1).replace('+', ''):<20}")
        for n in self.unobserved:
            lines.append(f"{n:<10} never observed: position unchanged")
        lines.append(f"{self.frames_used} of {self.frames_total} frames, {self.observations_used} observations, "
                     f"reprojection RMS {self.reprojection_rms_px:.2f} px; scale held by "
                     + ", ".join(f"|{a}-{b}| = {d:g} m" for a, b, d in self.scale)
                     + f"; sigmas for {self.pixel_sigma:g} px noise"
                     + ("" if self.prior_sigma is None else f" and the given positions good to {self.prior_sigma:g} m"))
        if self.outliers:
            lines.append(f"{len(self.outliers)} observations down-weighted as outliers (largest "
                         f"{max(o['residual_px'] for o in self.outliers):.1f} px)")
        for w in self.weak_directions:
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
    its poses relative to its first robot; and why nothing was, if so."""
    counts: dict[tuple[str, str], int] = {}
    for o, m in zip(obs.observer, obs.marker):
        w = rig.owner(m)
        key = (o, w) if order.index(o) < order.index(w) else (w, o)
        counts[key] = counts.get(key, 0) + 1
    from .api import localize

    edges: dict[str, dict[str, Pose]] = {}
    why = None
    for (a, b), n in counts.items():
        if n < MIN_PAIR_OBSERVATIONS:
            why = why or f"{a}-{b}: {n} observations (at least {MIN_PAIR_OBSERVATIONS} needed)"
            continue
        try:
            # confidence 1: the rig is only approximate here; the adjustment judges the fit.
            est = localize(rig, obs, source=b, target=a, pixel_sigma=pixel_sigma, confidence=1.0)
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


# ---------------------------------------------------------------------------
# the calibration
# ---------------------------------------------------------------------------


def calibrate_markers(rig: Any, log_or_frames: Any, scale: Any = None, pixel_sigma: float = 1.0, *,
                      prior_sigma: float | None = None, confidence: float = DEFAULT_CONFIDENCE,
                      huber: float = HUBER_K, max_iter: int = 100) -> CalibrationResult:
    """Re-estimate every observed marker's position from a sequence of mutual
    observations (SPEC "Marker calibration").

    ``log_or_frames``: an observation log's path (JSON Lines) or a sequence
    of frames (ObservationSets or the SPEC's observation dicts), any number
    of robots; markers of unknown identity are not used.  ``scale``:
    distances held fixed (``"A:B=D"`` strings or ``(A, B, D)``; markers A
    and B of one robot); default the two markers of the rig's first robot
    farthest apart, at their given distance.  ``pixel_sigma`` is the
    detection noise behind ``position_sigma``; observations whose residual
    fails the chi-square test (family-wise at ``confidence`` over the log)
    are reported as outliers and left out of a second fit (a Huber loss at
    ``huber`` sigma bounds their pull in the first).  Raises
    UnobservableMarkersError when the sequence cannot determine the markers.

    ``prior_sigma`` (metres, 1 sigma per axis; default None: the log alone)
    says how well the given positions were measured: they then count as a
    measurement, and the combinations the log determines only weakly stay
    near them instead of drifting (``position_sigma`` includes it; the weak
    directions and the refusal are judged on the log alone).
    """
    from .api import load_rig

    rig = load_rig(rig)
    pixel_sigma = positive_number(pixel_sigma, "pixel_sigma")
    huber = positive_number(huber, "huber")
    if prior_sigma is not None:
        prior_sigma = positive_number(prior_sigma, "prior_sigma")
    order = list(rig.robots)
    frames = _read_frames(log_or_frames)
    named = _check_scale(rig, parse_scale(scale))
    data = _collect(rig, frames, order, pixel_sigma)

    # Unknowns: the observed markers, in rig order.
    observed = {r[4] for r in data.rows}
    names = [n for r in order for n in rig.robots[r].markers if n in observed]
    unobserved = [n for r in order for n in rig.robots[r].markers if n not in observed]
    mindex = {n: i for i, n in enumerate(names)}
    named = named or [_default_scale(rig, order, observed)]
    for a, b, _ in named:
        for n in (a, b):
            if n not in mindex:
                raise UnobservableMarkersError(f"scale {a}:{b}: marker {n!r} is never observed in the log, so its "
                                               "distance cannot hold the scale")
    constraints = tuple((mindex[a], mindex[b], d) for a, b, d in named)
    old = np.array([rig.marker(n).position for n in names])
    prior = (old, (pixel_sigma / prior_sigma) ** 2) if prior_sigma is not None else (None, 0.0)
    fit = _fit(rig, order, data, mindex, constraints, prior, old, pixel_sigma, huber, max_iter, confidence)
    adj, groups = fit.adjustment, fit.groups

    _, C = constraint_jacobian(adj.markers, constraints)
    cov_post, _ = adj.marker_covariance(C, pixel_sigma)
    marker_robot = [rig.owner(n) for n in names]
    weak = _weak_directions(adj, C, names, marker_robot, _motion_summary(groups, adj, order), pixel_sigma,
                            fit.frames_used)
    sigma = np.sqrt(np.clip(np.diag(cov_post), 0.0, None)).reshape(-1, 3)
    markers = {n: MarkerCalibration(n, marker_robot[j], old[j], adj.markers[j].copy(), sigma[j])
               for j, n in enumerate(names)}
    new_rig = rig.to_dict()
    for n, m in markers.items():
        spec = new_rig["robots"][m.robot]["markers"][n]
        spec["position"] = m.new.tolist()
        spec["position_sigma"] = m.sigma.tolist()
    for n in unobserved:
        # A sigma from an earlier calibration no longer describes this rig's position.
        new_rig["robots"][rig.owner(n)]["markers"][n].pop("position_sigma", None)
    poses = [{"frame": g.frame, "reference": g.anchor,
              "poses": {r: Pose(adj.R[gi, s].copy(), adj.t[gi, s].copy()) for s, r in enumerate(g.members)}}
             for gi, g in enumerate(groups)]
    return CalibrationResult(
        rig=new_rig, markers=markers, weak_directions=weak, scale=list(named), pixel_sigma=pixel_sigma,
        covariance=cov_post, covariance_markers=names, prior_sigma=prior_sigma, frames_total=len(frames),
        frames_used=fit.frames_used, observations_used=len(fit.rows),
        reprojection_rms_px=float(np.sqrt(np.mean(np.sum(adj.residuals**2, axis=1)))), chi2=adj.chi2,
        dof=fit.dof, iterations=adj.iterations, converged=adj.converged, outliers=fit.outliers,
        unobserved=unobserved, skipped_frames=data.skipped, poses=poses)


def _check_scale(rig: Rig, named: list[tuple[str, str, float]]) -> list[tuple[str, str, float]]:
    """The held distances, each between two known markers of one robot."""
    for a, b, _ in named:
        for n in (a, b):
            try:
                rig.owner(n)
            except UnknownMarkerError:
                known = sorted(x for r in rig.robots.values() for x in r.markers)
                raise UnknownMarkerError(f"scale {a}:{b}: unknown marker {n!r} (rig has {', '.join(known)})"
                                         ) from None
        if rig.owner(a) != rig.owner(b):
            raise InputError(f"scale {a}:{b}: markers of different robots ({rig.owner(a)!r}, {rig.owner(b)!r}); "
                             "a held distance is between two markers of one robot")
        if a == b:
            raise InputError(f"scale {a}:{b}: a marker's distance to itself")
    return named


@dataclass
class _Collected:
    groups: list[_Group]
    rows: list[tuple]                     # group, observer slot, owner slot, camera, marker, u, v
    row_info: list[tuple[int, str, str]]  # frame, observer, marker
    skipped: list[dict[str, Any]]


def _collect(rig: Rig, frames: list[ObservationSet], order: list[str], pixel_sigma: float) -> _Collected:
    """Every frame on its own: its groups with their initial poses, and the observation rows."""
    out = _Collected([], [], [], [])
    for k, frame in enumerate(frames):
        obs = frame.best()
        if any(m is None for m in obs.marker):
            obs = obs.take(np.array([m is not None for m in obs.marker]))
        where = f"frame {k}" + ("" if np.all(np.isnan(obs.time)) else f" (time {obs.time[0]:g})")
        try:
            obs.check(rig)
        except MutlocError as exc:
            raise type(exc)(f"{where}: {exc}") from None
        fg, why = _frame_groups(rig, obs, k, order, pixel_sigma)
        if not fg:
            out.skipped.append({"frame": k, "reason": why})
            continue
        for grp in fg:
            gi = len(out.groups)
            out.groups.append(grp)
            slot = {r: i for i, r in enumerate(grp.members)}
            slot[grp.anchor] = -1
            for o, m, (u, v) in zip(obs.observer, obs.marker, obs.uv.tolist()):
                w = rig.owner(m)
                if o in slot and w in slot:
                    out.rows.append((gi, slot[o], slot[w], order.index(o), m, u, v))
                    out.row_info.append((k, o, m))
    if not out.groups:
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


def _fit(rig: Rig, order: list[str], data: _Collected, mindex: dict[str, int], constraints: tuple, prior: tuple,
         start: np.ndarray, pixel_sigma: float, huber: float, max_iter: int, confidence: float) -> _Fit:
    """The bundle adjustment; observations failing their own chi-square test
    are reported and left out of a second fit (the Huber loss bounds their
    pull but does not remove it).  The test is family-wise at
    ``confidence``: a log without a stray detection passes whole with that
    probability, however long it is."""
    groups, rows = data.groups, data.rows
    problem, R0, t0 = _problem(rig, order, groups, rows, mindex, constraints, prior)
    frames_used = len({g.frame for g in groups})
    if problem.dof < 0:
        raise UnobservableMarkersError(
            f"too few frames: {frames_used} usable frame{'s' if frames_used != 1 else ''} give "
            f"{2 * len(rows)} measurements for {problem.n_pose_parameters} pose and "
            f"{3 * len(mindex) - len(constraints)} marker unknowns; record more frames while the robots move "
            "(different distances, turning in place while facing each other, rolling)")
    adj = adjust(problem, start, R0, t0, pixel_sigma=pixel_sigma, huber=huber, max_iter=max_iter)
    gate = chi2_quantile(1.0 - (1.0 - confidence) / len(rows), 2) * pixel_sigma**2 if confidence < 1.0 else math.inf
    e2 = np.sum(adj.residuals**2, axis=1)
    info = data.row_info
    outliers = [{"frame": info[i][0], "observer": info[i][1], "marker": info[i][2],
                 "residual_px": float(np.sqrt(e2[i]))} for i in np.flatnonzero(e2 > gate)]
    if outliers:
        for gi, grp in enumerate(groups):
            for s, r in enumerate(grp.members):
                grp.poses[r] = Pose(adj.R[gi, s].copy(), adj.t[gi, s].copy())
        groups, rows = _without(groups, rows, e2 <= gate)
        if not groups:
            raise UnobservableMarkersError("no frame is left once the observations that fail their chi-square test "
                                           f"at {pixel_sigma:g} px are set aside: is --pixel-sigma right?")
        problem, R0, t0 = _problem(rig, order, groups, rows, mindex, constraints, prior)
        frames_used = len({g.frame for g in groups})
        adj = adjust(problem, adj.markers, R0, t0, pixel_sigma=pixel_sigma, huber=huber, max_iter=max_iter)
    return _Fit(adj, groups, rows, outliers, frames_used, problem.dof)


def _weak_directions(adj: Any, C: np.ndarray, names: list[str], marker_robot: list[str], motion: "_Motion",
                     pixel_sigma: float, frames_used: int) -> list[WeakDirection]:
    """The combinations the log alone determines weakly, weakest first;
    UnobservableMarkersError when one is not determined at all."""
    cov, eig = adj.marker_covariance(C, pixel_sigma, data_only=True)
    if not np.all(np.isfinite(eig)) or eig[0] <= SINGULAR_RATIO * eig[-1]:
        Z = null_space(C, 3 * len(names))
        S = adj.information - adj.prior_weight * np.eye(3 * len(names))
        v = Z @ np.linalg.eigh(0.5 * (Z.T @ S @ Z + (Z.T @ S @ Z).T))[1][:, 0]
        raise UnobservableMarkersError(
            f"the log cannot determine the markers: {_describe(v, names, marker_robot)} changes no pixel "
            f"({frames_used} usable frames{motion.note}). {_advice(v, motion)}")
    w, V = np.linalg.eigh(cov)
    w = np.clip(w, 0.0, None)[::-1]
    V = V[:, ::-1]
    sig = np.sqrt(w)
    if sig[0] > MAX_SIGMA_M:
        raise UnobservableMarkersError(
            f"the log cannot determine the markers: {_describe(V[:, 0], names, marker_robot)} is known only to "
            f"{sig[0] * 1000:.0f} mm (1 sigma at {pixel_sigma:g} px; {frames_used} usable frames{motion.note}). "
            f"{_advice(V[:, 0], motion)}")
    free = sig[: 3 * len(names) - C.shape[0]]
    med = float(np.median(free)) if len(free) else 0.0
    weak = []
    for i in range(len(free)):
        if sig[i] > WEAK_RATIO * med and sig[i] > WEAK_MIN_M:
            v = V[:, i]
            weak.append(WeakDirection(float(sig[i]), _describe(v, names, marker_robot), _advice(v, motion),
                                      {n: v[3 * j:3 * j + 3].tolist() for j, n in enumerate(names)}))
    return weak


def _problem(rig: Rig, order: list[str], groups: list[_Group], rows: list[tuple], mindex: dict[str, int],
             constraints: tuple, prior: tuple) -> tuple[BundleProblem, np.ndarray, np.ndarray]:
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
    arr = np.array([(r[0], r[1], r[2], r[3]) for r in rows], dtype=np.int64).reshape(-1, 4)
    problem = BundleProblem(
        group=np.ascontiguousarray(arr[:, 0]), observer_slot=np.ascontiguousarray(arr[:, 1]),
        owner_slot=np.ascontiguousarray(arr[:, 2]), camera=np.ascontiguousarray(arr[:, 3]),
        marker=np.array([mindex[r[4]] for r in rows], dtype=np.int64),
        uv=np.array([(r[5], r[6]) for r in rows], dtype=float).reshape(-1, 2),
        K=np.ascontiguousarray(np.stack([rig.robots[r].camera.K for r in order])),
        dist=np.ascontiguousarray(np.stack([rig.robots[r].camera.dist for r in order])),
        slot_used=slot_used, n_markers=len(mindex), constraints=constraints, prior=prior[0], prior_weight=prior[1])
    return problem, R0, t0


def _without(groups: list[_Group], rows: list[tuple], keep: np.ndarray) -> tuple[list[_Group], list[tuple]]:
    """The groups and rows left when only rows ``keep`` are used; a group in
    which a robot keeps fewer than three observations is dropped whole."""
    count: dict[tuple[int, int], int] = {}
    for r, k in zip(rows, keep):
        if k:
            for s_ in (r[1], r[2]):
                count[(r[0], s_)] = count.get((r[0], s_), 0) + 1
    ok = [all(count.get((gi, s_), 0) >= 3 for s_ in range(-1, len(g.members))) for gi, g in enumerate(groups)]
    renum = {gi: k for k, gi in enumerate(gi for gi in range(len(groups)) if ok[gi])}
    new_rows = [(renum[r[0]],) + tuple(r[1:]) for r, k in zip(rows, keep) if k and ok[r[0]]]
    return [g for gi, g in enumerate(groups) if ok[gi]], new_rows


def _default_scale(rig: Rig, order: list[str], observed: set[str]) -> tuple[str, str, float]:
    """SPEC: the two markers farthest apart on the first robot, at their given distance."""
    first = order[0]
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


def _describe(v: np.ndarray, names: Sequence[str], marker_robot: Sequence[str]) -> str:
    """A marker-space direction in words: per robot, how its markers move."""
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
            parts.append(_AXIS_WORDS[k][0 if mean[k] > 0 else 1].format(r=r))
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


_ROLL_ADVICE = ("The robots hardly roll relative to each other: roll one robot about its optical axis during the "
                "recording (or tilt it), or add a third robot that sees both")
_TURN_ADVICE = ("The robots hardly turn relative to each other: turn one robot in place further (yaw) while it faces "
                "the other, record from more distances, or add a third robot that sees both")


def _advice(v: np.ndarray, motion: _Motion) -> str:
    """The motion that would determine direction ``v``: the log's own
    shortcoming when it has an obvious one, else by the axis ``v`` moves along."""
    if motion.specific:
        return motion.advice
    shift = np.abs(np.asarray(v, float).reshape(-1, 3)).sum(axis=0)
    return _ROLL_ADVICE if int(np.argmax(shift)) == 1 else _TURN_ADVICE


def _motion_summary(groups: list[_Group], adj: Any, order: list[str]) -> _Motion:
    """What the log's relative poses did, and the motion that would add what is missing."""
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
                           specific=k == 1)
    return _Motion("", general, specific=False)

"""Teams: :func:`localize_team` estimates every robot's pose in one
reference robot's frame, jointly, from all observations (SPEC "Teams")."""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, Mapping

import numpy as np

from .api import Estimate, load_rig
from .core.consistency import DEFAULT_CONFIDENCE, Consistency, chi2_quantile
from .core.observations import ObservationSet
from .core.pose import Pose
from .core.rays import set_aside_past_rim
from .core.rig import Rig
from .core.team import (AMBIGUITY_SIGMAS, MIN_TIES, TeamProblem, TeamSolution, checked_factor, inverse_from_factor,
                        misfit_robots, other_poses, relative_jacobian, residual_norms, solve_team)
from .errors import (DegenerateGeometryError, InconsistentObservationsError, MutlocError, ObservationError,
                     TooFewObservationsError, UnverifiedError, confidence_level, positive_number)

__all__ = ["TeamEstimate", "localize_team", "localize_team_images", "team_problem", "in_rays", "require_verified"]


@dataclass(eq=False)
class TeamEstimate:
    """Every localized robot's pose ``T_ref_r`` (``x_ref = R @ x_r + t``)
    in the frame of robot ``reference``, with the joint covariance.

    ``information`` is ``J^T J`` (pixels^-2) over :attr:`robots`; the joint
    covariance is computed from it on first use.  ``unverified`` lists
    robots held by exactly three observations: several
    poses fit those exactly and nothing can confirm the one chosen (as a
    pair's ``"unverified"`` status) -- and robots whose few observations fit
    a second, distant pose within their noise as well: ``ambiguous`` holds
    those other poses (``T_ref_r``, best first; :meth:`candidates`) -- and
    robots whose own observations fit far worse than the team's residuals
    say the noise is (``misfit``; :func:`mutloc.core.team.misfit_robots`)."""

    reference: str
    poses: dict[str, Pose]
    robots: list[str]
    unlocalized: list[str]
    information: np.ndarray
    pixel_sigma: float
    reprojection_rms_px: float
    observations_used: int
    consistency: Consistency
    unverified: list[str] = field(default_factory=list)
    ambiguous: dict[str, Pose] = field(default_factory=dict)
    misfit: list[str] = field(default_factory=list)
    rejected: list[dict[str, Any]] = field(default_factory=list)
    markers_between: dict[frozenset, list[str]] = field(default_factory=dict)
    extra: dict[str, Any] = field(default_factory=dict)
    factor: tuple[np.ndarray, np.ndarray] | None = field(default=None, repr=False)

    @cached_property
    def joint_covariance(self) -> np.ndarray:
        """``pixel_sigma^2 (J^T J)^-1``, 6k square over :attr:`robots` (computed on first use)."""
        if self.information.size == 0:
            return np.zeros((0, 0))
        factor = self.factor if self.factor is not None else checked_factor(self.information)
        return self.pixel_sigma**2 * inverse_from_factor(*factor)

    @property
    def status(self) -> str:
        """``"solved"`` (the joint residual passed its chi-square test) or
        ``"unverified"`` (no redundancy: as many equations as unknowns)."""
        passed = self.consistency.passed
        return "unverified" if passed is None else ("solved" if passed else "rejected")

    def robot_status(self, name: str) -> str:
        """``name``'s own status: ``"unverified"`` when it is listed in
        :attr:`unverified`, else the team's :attr:`status`."""
        self._block(name)
        return "unverified" if name in self.unverified else self.status

    def candidates(self, name: str) -> Pose:
        """Every pose ``T_ref_name`` the observations fit within their noise
        (a stack): the estimate first, then the :attr:`ambiguous` others."""
        self._block(name)
        pose = self.poses[name]
        return Pose.concatenate([pose, *self.ambiguous[name]]) if name in self.ambiguous else \
            Pose.concatenate([pose])

    def _block(self, name: str) -> int:
        if name == self.reference:
            return -1
        if name in self.unlocalized:
            raise ObservationError(f"robot {name!r} is not localized (nothing ties it to {self.reference!r})")
        if name not in self.poses:
            raise ObservationError(f"unknown robot {name!r} (team has {sorted([*self.poses, *self.unlocalized])})")
        return self.robots.index(name)

    def covariance(self, name: str) -> np.ndarray:
        """6x6 covariance of ``T_ref_name`` (zero for the reference)."""
        i = self._block(name)
        if i < 0:
            return np.zeros((6, 6))
        return self.joint_covariance[6 * i:6 * i + 6, 6 * i:6 * i + 6].copy()

    def relative(self, a: str, b: str) -> Estimate:
        """``T_ba`` (``x_b = R @ x_a + t``) as an :class:`Estimate` whose
        covariance is propagated from the joint one (correlations included)."""
        ia, ib = self._block(a), self._block(b)
        if a == b:
            raise ObservationError(f"relative pose of robot {a!r} to itself")
        Ta, Tb = self.poses[a], self.poses[b]
        Ja, Jb = relative_jacobian(Ta.R, Ta.t, Tb.R, Tb.t)
        blocks = [(Ja, ia), (Jb, ib)]
        cov = np.zeros((6, 6))
        for J1, i1 in blocks:
            for J2, i2 in blocks:
                if i1 >= 0 and i2 >= 0:
                    cov += J1 @ self.joint_covariance[6 * i1:6 * i1 + 6, 6 * i2:6 * i2 + 6] @ J2.T
        pose = Tb.inverse() @ Ta
        return Estimate(source=a, target=b, pose=pose, covariance=0.5 * (cov + cov.T), pixel_sigma=self.pixel_sigma,
                        reprojection_rms_px=self.reprojection_rms_px,
                        markers_used=list(self.markers_between.get(frozenset((a, b)), [])),
                        candidates=Pose.concatenate([pose]), consistency=self.consistency,
                        extra={"team_reference": self.reference})

    def to_dict(self) -> dict[str, Any]:
        """The team result JSON of SPEC (plus ``status`` and ``consistency``)."""
        robots = {}
        for name in self.robots:
            d = self.poses[name].to_dict()
            d["covariance"] = self.covariance(name).tolist()
            robots[name] = d
        return {"reference": self.reference, "robots": robots, "unlocalized": list(self.unlocalized),
                "reprojection_rms_px": float(self.reprojection_rms_px), "pixel_sigma": float(self.pixel_sigma),
                "observations_used": int(self.observations_used), "status": self.status,
                "consistency": self.consistency.to_dict(), "unverified": list(self.unverified),
                **({"ambiguous": {n: [T.to_dict() for T in P] for n, P in self.ambiguous.items()}}
                   if self.ambiguous else {}),
                **({"rejected": [dict(r) for r in self.rejected]} if self.rejected else {})}


def team_problem(rig: Rig, observations: ObservationSet) -> tuple[TeamProblem, list[str], list[str]]:
    """The solver's form of named observations (checked against the rig):
    the problem, the robot names (rig order) and each row's marker name.

    Observations are keyed by camera (``ROBOT/CAMERA``, or ``ROBOT`` for a
    robot with one camera; SPEC "Robots with several cameras").  When every
    robot is one pinhole camera the problem is in pixels; otherwise each row
    is a ray of its observing robot's frame (:func:`mutloc.core.rays.ray_frames`,
    ``TeamProblem.frames``: ray mode, whatever the lens).

    Checked with NumPy over all rows at once; anything unusual (an error to
    name, several candidates for one marker, unnamed markers) takes the
    row-by-row path, which raises the error naming observer and marker."""
    central = rig.central_pinhole
    names = list(rig.robots)
    index = {n: i for i, n in enumerate(names)}
    mrow: dict[str, int] = {}
    mown: list[int] = []
    pts: list[Any] = []
    for i, n in enumerate(names):
        robot = rig.robots[n]
        for m, marker in robot.markers.items():
            mrow[m] = len(pts)
            mown.append(i)
            pts.append(marker.position)
    obs = observations
    if central:
        sizes = np.full((len(names), 2), np.inf)
        for i, n in enumerate(names):
            if rig.robots[n].camera.size is not None:
                sizes[i] = rig.robots[n].camera.size
    try:
        if central:
            cam = np.array([index[o] for o in obs.observer], dtype=np.int64)
            key = cam
        else:
            # each camera its own key: its image size, its rows' rays
            keys = {o: rig.observer(o) for o in dict.fromkeys(obs.observer)}
            kindex = {o: i for i, o in enumerate(keys)}
            sizes = np.full((len(keys), 2), np.inf)
            for o, k in kindex.items():
                size = rig.robots[keys[o][0]].mounts[keys[o][1]].camera.size
                if size is not None:
                    sizes[k] = size
            key = np.array([kindex[o] for o in obs.observer], dtype=np.int64)
            cam = np.array([index[keys[o][0]] for o in obs.observer], dtype=np.int64)
        row = np.array([mrow[m] for m in obs.marker], dtype=np.int64)
    except (KeyError, TypeError, ObservationError):  # unknown robot, camera or marker, unnamed marker
        return _team_problem_rows(rig, obs, names)
    own = np.array(mown, dtype=np.int64)[row]
    u, v = obs.uv[:, 0], obs.uv[:, 1]
    W, H = sizes[key, 0], sizes[key, 1]
    bad = (cam == own) | ~((-0.5 * W <= u) & (u <= 1.5 * W) & (-0.5 * H <= v) & (v <= 1.5 * H))
    timed = ~np.isnan(obs.time)
    if (bad.any() or (timed.any() and not timed.all()) or np.unique(obs.time[timed]).size > 1
            or np.unique(key * len(pts) + row).size < len(row)):
        return _team_problem_rows(rig, obs, names)
    points = np.array(pts, dtype=float).reshape(-1, 3)[row]
    return _problem(rig, names, obs, cam, own, points), names, list(obs.marker)


def _problem(rig: Rig, names: list[str], obs: ObservationSet, cam: np.ndarray, own: np.ndarray,
             points: np.ndarray) -> TeamProblem:
    """The TeamProblem of checked rows: pixels through each robot's one
    pinhole camera, or rays (any cameras, any lens)."""
    if rig.central_pinhole:
        K = np.array([rig.robots[n].camera.K for n in names])
        dist = np.array([rig.robots[n].camera.dist for n in names])
        return TeamProblem(cam, own, points, obs.uv, K, dist, 1.0 / obs.sigma_scale)
    from .core.rays import ray_frames

    frames = np.empty((len(cam), 4, 3))
    groups: dict[str, list[int]] = {}
    for i, o in enumerate(obs.observer):
        groups.setdefault(o, []).append(i)
    for o, idx in groups.items():
        ix = np.asarray(idx, dtype=np.int64)
        _, frames[ix] = ray_frames(rig.mount(o), obs.uv[ix],
                                   lambda k, ix=ix, o=o: f"observations[{o!r}][{obs.marker[int(ix[k])]!r}]")
    # (K and dist are unused in ray mode)
    K = np.tile(np.eye(3), (len(names), 1, 1))
    return TeamProblem(cam, own, points, obs.uv, K, np.zeros((len(names), 8)), 1.0 / obs.sigma_scale, frames)


def in_rays(rig: Rig, names: list[str], problem: TeamProblem) -> TeamProblem:
    """``problem`` (of :func:`team_problem`, robots ``names``) in ray mode:
    each row's ray through its camera, in its robot's frame (already so: itself)."""
    if problem.frames is not None:
        return problem
    from .core.rays import ray_frames

    frames = np.empty((len(problem.cam), 4, 3))
    for a in np.unique(problem.cam).tolist():
        ix = np.flatnonzero(problem.cam == a)
        _, frames[ix] = ray_frames(rig.mount(names[a]), problem.uv[ix])
    return TeamProblem(problem.cam, problem.own, problem.points, problem.uv, problem.K, problem.dist, problem.wt,
                       frames)


def _team_problem_rows(rig: Rig, observations: ObservationSet, names: list[str]) -> tuple[TeamProblem, list[str],
                                                                                          list[str]]:
    """:func:`team_problem` row by row (errors named as for a pair; the best
    of several candidates per marker)."""
    obs = observations.check(rig)
    if obs.has_alternatives:
        obs = obs.best()
    if any(m is None for m in obs.marker):
        raise ObservationError("teams need named markers (a list of unnamed pixels is ambiguous across robots)")
    times = obs.time[~np.isnan(obs.time)]
    if times.size and np.unique(times).size > 1:
        raise ObservationError("observations of several times: localize one frame at a time (at_time)")
    index = {n: i for i, n in enumerate(names)}
    cam = np.array([index[rig.observer(o)[0]] for o in obs.observer], dtype=np.int64)
    owners = [rig.owner(m) for m in obs.marker]
    own = np.array([index[o] for o in owners], dtype=np.int64)
    points = np.array([rig.robots[o].markers[m].position for o, m in zip(owners, obs.marker)]).reshape(-1, 3)
    return _problem(rig, names, obs, cam, own, points), names, list(obs.marker)


def localize_team(rig: Any, observations: ObservationSet | Mapping[str, Any], reference: str | None = None, *,
                  pixel_sigma: float = 1.0, confidence: float = DEFAULT_CONFIDENCE,
                  initial: Mapping[str, Pose] | None = None, max_iter: int = 50,
                  reject_outliers: bool = True) -> TeamEstimate:
    """Every robot's pose in robot ``reference``'s frame (default: the rig's
    first robot), estimated jointly: one maximum-likelihood problem over the
    pixel reprojection error of every observation (any camera seeing any
    other robot's marker, mutual or one-sided), with the joint covariance for
    isotropic detection noise ``pixel_sigma``.

    Robots nothing ties to the reference are listed in ``unlocalized``
    (never guessed); a robot -- or a group of robots solved among
    themselves -- is tied once three observations, by any cameras, link it
    to robots already tied (see :func:`mutloc.core.team.initial_poses`);
    held by exactly three, it is listed in ``unverified`` -- as is a robot
    held by a few more (up to six) whose observations fit a second pose,
    far beyond its covariance, within their noise: those other poses are in
    ``ambiguous`` and :meth:`TeamEstimate.candidates`
    (:func:`mutloc.core.team.other_poses`).
    ``initial`` (``{robot: T_ref_robot}``, e.g. the previous frame's poses)
    replaces the initialisation from the pair solvers; robots missing from
    it are unlocalized.  The joint residual is tested against its noise
    (chi-square, ``2n - 6k`` degrees of freedom for ``n`` observations and
    ``k`` robots); failing it raises
    :class:`~mutloc.errors.InconsistentObservationsError` carrying the
    estimate (``confidence=1`` disables the test).  Before that, with
    ``reject_outliers``, the worst-fitting observation is dropped and the
    team solved again, up to a fifth of the observations; those dropped are
    named in ``rejected``.
    """
    rig = load_rig(rig)
    pixel_sigma = positive_number(pixel_sigma, "pixel_sigma")
    confidence_level(confidence)
    names = list(rig.robots)
    if len(names) < 2:
        raise ObservationError(f"a team needs at least two robots; the rig has {len(names)}")
    if reference is None:
        reference = names[0]
    if not isinstance(reference, str) or reference not in rig.robots:
        raise ObservationError(f"unknown reference robot {reference!r} (rig has {sorted(rig.robots)})")
    observations = ObservationSet.from_dict(observations)
    try:
        problem, names, markers = team_problem(rig, observations)
        aside: list[dict[str, Any]] = []
    except ObservationError:
        # a pixel noise pushed a little past a lens's rim: set aside and named in ``rejected``, not a refusal
        observations, aside = set_aside_past_rim(rig, observations, pixel_sigma)
        if not aside:
            raise
        problem, names, markers = team_problem(rig, observations)
    ref = names.index(reference)
    start = None
    if initial is not None:
        Rs = np.tile(np.eye(3), (len(names), 1, 1))
        ts = np.zeros((len(names), 3))
        loc = np.zeros(len(names), dtype=bool)
        for n, T in initial.items():
            if n not in rig.robots:
                raise ObservationError(f"initial: unknown robot {n!r}")
            i = names.index(n)
            Rs[i], ts[i], loc[i] = T.R, T.t, True
        start = (Rs, ts, loc)
    keep = np.arange(len(problem.cam))
    rejected: list[dict[str, Any]] = list(aside)
    while True:
        sub = problem.take(keep)
        sol = solve_team(sub, ref, initial=start, max_iter=max_iter, sigma=pixel_sigma, confidence=confidence)
        if len(sol.order) == 0:
            seen = sorted({names[i] for i in np.r_[problem.cam, problem.own].tolist()})
            raise TooFewObservationsError(
                f"no robot is tied to the reference {reference!r} by three or more observations "
                f"({len(problem.cam)} observations among {seen or 'no robots'})")
        test = _test(sol, pixel_sigma, confidence)
        if test.passed is False:
            # a weakly tied robot in a wrong basin fails the test as an
            # outlier would: its other poses first (see other_poses)
            try:
                sol = other_poses(sub, sol, ref, sigma=pixel_sigma, confidence=confidence, max_iter=max_iter)[0]
            except DegenerateGeometryError:
                pass
            test = _test(sol, pixel_sigma, confidence)
        if test.passed is not False or not reject_outliers or len(rejected) - len(aside) >= len(problem.cam) // 5:
            break
        # drop the worst-fitting observation and solve again from scratch
        # (a wrong detection may have misled the start as well)
        err = residual_norms(sub.take(sol.used), sol.Rs, sol.ts)
        k = int(keep[sol.used[int(np.argmax(err))]])
        rejected.append({"observer": names[problem.cam[k]], "marker": markers[k], "residual_px": float(np.max(err))})
        keep = keep[keep != k]
        start = None
    others: dict[int, list] = {}
    if test.passed is not False:
        # a weakly tied robot may fit a second pose as well as the optimum
        # (as a pair on three markers): not verified, its poses the candidates
        try:
            sol, others = other_poses(sub, sol, ref, sigma=pixel_sigma, confidence=confidence, max_iter=max_iter)
        except DegenerateGeometryError:
            others = {}
        test = _test(sol, pixel_sigma, confidence)
    # a robot whose ties fit far worse than the team's residuals say the
    # noise is: in a wrong basin, though the joint test passes
    misfit = set(misfit_robots(sub, sol, pixel_sigma, confidence)) if test.passed is not False else set()
    try:
        est = _estimate(sol, names, [markers[k] for k in keep], sub, reference, pixel_sigma, test, others, misfit)
    except DegenerateGeometryError:
        if test.passed is not False:
            raise
        est = None
    if est is not None:
        est.rejected = rejected
    if test.passed is False:
        raise InconsistentObservationsError(
            f"the team's observations do not fit one set of poses with {pixel_sigma:g} px noise (chi2 {test.chi2:.1f} "
            f"over {test.dof} degrees of freedom, above {test.threshold:.1f} at {100 * confidence:g}%"
            + (f", even without the {len(rejected) - len(aside)} worst observations" if len(rejected) > len(aside)
               else "")
            + "): a wrong detection, a wrong rig or more noise than --pixel-sigma says", est)
    return est


def _test(sol: TeamSolution, sigma: float, confidence: float) -> Consistency:
    """A pair's chi-square test (core.consistency) with six unknowns per robot."""
    dof = sol.dof
    threshold = chi2_quantile(confidence, dof) if dof > 0 else np.inf
    return Consistency(float(sol.cost) / sigma**2, dof, confidence, threshold)


def _estimate(sol: TeamSolution, names: list[str], markers: list[str], problem: TeamProblem, reference: str,
              sigma: float, test: Consistency, others: Mapping[int, list] | None = None,
              misfit: set[int] | None = None) -> TeamEstimate:
    robots = [names[i] for i in sol.order]
    poses = {names[i]: Pose(sol.Rs[i].copy(), sol.ts[i].copy()) for i in np.flatnonzero(sol.localized)}
    poses[reference] = Pose.identity()
    between: dict[frozenset, list[str]] = {}
    ties = np.zeros(len(names), dtype=np.int64)
    for j in sol.used.tolist():
        a, b = int(problem.cam[j]), int(problem.own[j])
        between.setdefault(frozenset((names[a], names[b])), []).append(markers[j])
        ties[a] += 1
        ties[b] += 1
    # a robot held by three observations fits several poses exactly -- and so
    # does a group of robots held to the reference's side by three: every
    # robot whose every tie to the reference crosses such a cut
    unverified = _weakly_tied(sol, problem, names.index(reference))
    # a second consistent pose far beyond the covariance: the observations
    # cannot tell which is right; closer ones only widen the candidates of a
    # robot unverified already
    others = others or {}
    far = {i for i, alts in others.items() if max(a[3] for a in alts) > AMBIGUITY_SIGMAS}
    misfit = misfit or set()
    unverified = [names[i] for i in sol.order
                  if ties[i] <= MIN_TIES or i in unverified or i in far or i in misfit]
    ambiguous = {names[i]: Pose.concatenate([Pose(a[0], a[1]) for a in alts]) for i, alts in others.items()
                 if names[i] in unverified}
    est = TeamEstimate(
        reference=reference, poses=poses, robots=robots,
        unlocalized=[n for i, n in enumerate(names) if not sol.localized[i]],
        information=sol.information, factor=checked_factor(sol.information) if sol.information.size else None,
        pixel_sigma=sigma,
        reprojection_rms_px=float(np.sqrt(sol.cost / max(sol.n_obs, 1))), observations_used=sol.n_obs,
        consistency=test, unverified=unverified, ambiguous=ambiguous,
        misfit=[names[i] for i in sol.order if i in misfit], markers_between=between,
        extra={"iterations": sol.iterations})
    return est


def _weakly_tied(sol: TeamSolution, problem: TeamProblem, reference: int) -> set[int]:
    """Robots separated from the reference by a cut of at most MIN_TIES used
    observations (max-flow = min-cut over the observation graph): the
    whole group beyond the cut then fits several poses exactly."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import maximum_flow

    n = len(sol.localized)
    cap = np.zeros((n, n), dtype=np.int32)
    for j in sol.used.tolist():
        a, b = int(problem.cam[j]), int(problem.own[j])
        cap[a, b] += 1
        cap[b, a] += 1
    # edge connectivity is transitive (lambda(a, c) >= min(lambda(a, b), lambda(b, c))):
    # more than MIN_TIES direct observations with a robot known to be held well
    # is enough, and max-flow is left for the rest (usually none)
    held = np.zeros(n, dtype=bool)
    held[reference] = True
    while True:
        more = ~held & sol.localized & ((cap[:, held] > MIN_TIES).any(axis=1))
        if not more.any():
            break
        held |= more
    rest = [int(i) for i in sol.order if not held[i]]
    if not rest:
        return set()
    graph = csr_matrix(cap)
    return {i for i in rest if maximum_flow(graph, reference, i).flow_value <= MIN_TIES}


def require_verified(team: TeamEstimate, allow_unverified: bool) -> None:
    """UnverifiedError when some robot rests on three observations and the
    caller did not accept that (the command line without ``--allow-unverified``)."""
    if team.unverified and not allow_unverified:
        few = [n for n in team.unverified if n not in team.ambiguous and n not in team.misfit]
        parts = []
        if team.misfit:
            parts.append(f"robot{'s' if len(team.misfit) > 1 else ''} {', '.join(team.misfit)}: its observations fit "
                         "far worse than the team's residuals say the noise is (a wrong pose, or a wrong detection)")
        if few:
            parts.append(f"robot{'s' if len(few) > 1 else ''} {', '.join(few)}: only three observations tie it to "
                         "the team, several poses fit them exactly and nothing can verify the one chosen")
        for n, P in team.ambiguous.items():
            far = max(float(np.max(np.atleast_1d(team.poses[n].rotation_error_deg(P)))), 0.0)
            parts.append(f"robot {n}: its observations fit {len(P) + 1} poses within their noise (up to "
                         f"{far:.0f} deg apart) and nothing can tell which is right")
        raise UnverifiedError(
            "; ".join(parts) + "; accept the risk with --allow-unverified or observe more markers", team)


def localize_team_images(rig: Any, images: Mapping[str, Any], reference: str | None = None,
                         **options: Any) -> Any:
    """Detect, in one image per camera (arrays or file paths), every other
    robot's markers and localize the team (``options`` as
    :func:`localize_team`); a ``FrameResult`` whose ``estimate`` is the
    :class:`TeamEstimate`.

    ``images`` is keyed as observations are: ``ROBOT`` for a robot with one
    camera, ``ROBOT/CAMERA`` for each camera of a robot with several (any
    lens; not every camera needs an image).  Each image is searched through
    its own lens (:func:`mutloc.track.frames.detect_markers`), and the team
    solved on the rays of all of them; ``detections`` are keyed likewise.
    When the team cannot be localized, the error raised carries the
    detections as its ``detections``."""
    from pathlib import Path

    from .detect.base import as_bgr
    from .track.frames import (FrameResult, detect_markers, expanded_rig, image_keys, observations_of, read_image,
                               same_images)

    rig = expanded_rig(load_rig(rig))
    image_keys(rig, images)  # every key a camera of the rig, each camera once (one-line errors)
    loaded = {k: as_bgr(read_image(img) if isinstance(img, (str, Path)) else img,
                        f"image of {'camera' if '/' in k else 'robot'} {k!r}") for k, img in images.items()}
    same_images(rig, loaded)
    detections = {k: detect_markers(rig, k, img) for k, img in loaded.items()}
    try:
        team = localize_team(rig, observations_of(detections), reference, **options)
    except MutlocError as exc:
        exc.detections = detections  # type: ignore[attr-defined]  # what was found, to write all the same
        raise
    return FrameResult(team, detections)  # type: ignore[arg-type]

"""The public entry points: :func:`localize` (pixels, named markers, a rig)
and :func:`solve_bearings` (rays, any camera model)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from itertools import permutations, product
from typing import Any, Callable, Iterator, Mapping, Sequence

import numpy as np

from .core.consistency import DEFAULT_CONFIDENCE, Consistency, chi2_quantile, consistency
from .core.estimate import PER_SUBSET, PairProblem, Solution, estimate, minimal_candidates_kernel, minimal_subsets
from .core.geometry import skew
from .core.observations import ObservationSet, PairObservations
from .core.pose import Pose
from .core.refine import tangent_bases
from .core.rays import pair_rays, set_aside_past_rim
from .core.rig import Rig
from .core.robust import (MIN_VERIFIABLE, NONLINEARITY_LIMIT, covariance_nonlinearity, largest_consistent_set,
                          observation_errors, other_consistent_poses)
from .errors import (InconsistentObservationsError, InputError, MutlocError, NoSolutionError, ObservationError,
                     UnverifiedError, confidence_level, positive_number)

__all__ = ["Estimate", "localize", "localize_batch", "solve_bearings", "load_rig", "invert_covariance"]

# Assignments of anonymous markers tried at most (keeps the search bounded).
MAX_ASSIGNMENTS = 5040


def load_rig(source: Any) -> Rig:
    """A :class:`Rig` from a YAML/JSON rig file, a dict in rig-file form, or a Rig."""
    if isinstance(source, Rig):
        return source
    from .io.rig import load_rig as _load

    return _load(source)


def invert_covariance(R: np.ndarray, t: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """Covariance of the inverse pose, same (left rotvec, translation) convention."""
    Rt = R.T
    J = np.zeros((6, 6))
    J[:3, :3] = -Rt
    J[3:, :3] = -Rt @ skew(t)
    J[3:, 3:] = -Rt
    return J @ cov @ J.T


@dataclass(eq=False)
class Estimate:
    """Relative pose ``T_qp`` (``x_q = R @ x_p + t``) from robot ``source``
    (p) to robot ``target`` (q), with its uncertainty.

    ``candidates``: every distinct pose of the minimal subsets, best first.
    When the first minimal subset :func:`localize` tries already gives an
    optimum that passes the consistency test, the other subsets are solved
    on the first read of ``candidates`` (a callable returning the stack may
    be given for it).
    """

    source: str
    target: str
    pose: Pose
    covariance: np.ndarray
    pixel_sigma: float
    reprojection_rms_px: float
    markers_used: list[str]
    candidates: Pose
    consistency: Consistency | None = None
    rejected: list[dict[str, Any]] = field(default_factory=list)
    identity_ambiguous: bool | None = None
    assignment: dict[str, dict[str, Any]] | None = None
    extra: dict[str, Any] = field(default_factory=dict)
    #: Other poses that fit the observations as well (each passes the test, and this pose's covariance rules it
    #: out): the observations do not decide between them; None when not searched.
    alternatives: Pose | None = None
    #: Robots with several cameras or wide-angle lenses: how far the cost at this pose's 3-sigma boundary along
    #: its weakest direction is from the covariance's quadratic model (:func:`~mutloc.core.robust.covariance_nonlinearity`),
    #: set when beyond :data:`~mutloc.core.robust.NONLINEARITY_LIMIT`: the covariance does not hold, the
    #: estimate is ``unverified``.  None otherwise.
    nonlinearity: float | None = None

    @property
    def status(self) -> str:
        """``"solved"`` (passed its consistency test, and no other pose does), ``"unverified"``
        (three observations: nothing to test; or another pose fits as well, see :attr:`alternatives`; or, robots
        with several cameras or wide-angle lenses, the covariance does not hold, see :attr:`nonlinearity`), or
        ``"rejected"`` (failed it; only ever seen on the estimate an InconsistentObservationsError carries)."""
        passed = None if self.consistency is None else self.consistency.passed
        if passed and ((self.alternatives is not None and len(self.alternatives)) or self.nonlinearity is not None):
            return "unverified"
        return "unverified" if passed is None else ("solved" if passed else "rejected")

    @property
    def R(self) -> np.ndarray:
        return self.pose.R

    @property
    def t(self) -> np.ndarray:
        return self.pose.t

    @property
    def quaternion_xyzw(self) -> np.ndarray:
        return self.pose.quaternion_xyzw

    def inverse(self) -> "Estimate":
        """The same estimate as ``T_pq`` (from target to source)."""
        return Estimate(
            source=self.target,
            target=self.source,
            pose=self.pose.inverse(),
            covariance=invert_covariance(self.R, self.t, self.covariance),
            pixel_sigma=self.pixel_sigma,
            reprojection_rms_px=self.reprojection_rms_px,
            markers_used=list(self.markers_used),
            candidates=self.candidates.inverse(),
            consistency=self.consistency,
            rejected=[dict(r) for r in self.rejected],
            identity_ambiguous=self.identity_ambiguous,
            assignment=self.assignment,
            extra=dict(self.extra),
            alternatives=None if self.alternatives is None else self.alternatives.inverse(),
            nonlinearity=self.nonlinearity,
        )

    def __getstate__(self) -> dict[str, Any]:
        # candidates solved before pickling or copying: the callable that
        # would solve them later does not travel
        state = dict(self.__dict__)
        state["_candidates"] = self.candidates
        return state

    def to_dict(self) -> dict[str, Any]:
        """The result JSON of SPEC (plus identity fields for anonymous markers)."""
        d: dict[str, Any] = {"from": self.source, "to": self.target}
        d.update(self.pose.to_dict())
        d.update({
            "reprojection_rms_px": float(self.reprojection_rms_px),
            "covariance": self.covariance.tolist(),
            "pixel_sigma": float(self.pixel_sigma),
            "markers_used": list(self.markers_used),
            "status": self.status,
        })
        if self.consistency is not None:
            d["consistency"] = self.consistency.to_dict()
        if self.rejected:
            d["rejected"] = [dict(r) for r in self.rejected]
        if self.identity_ambiguous is not None:
            d["identity_ambiguous"] = bool(self.identity_ambiguous)
            d["assignment"] = self.assignment
        if self.alternatives is not None and len(self.alternatives):
            d["alternatives"] = [p.to_dict() for p in self.alternatives]
        if self.nonlinearity is not None:
            d["covariance_nonlinearity"] = float(self.nonlinearity) if math.isfinite(self.nonlinearity) else None
        return d


def rejected_text(entries: Sequence[Mapping[str, Any]]) -> str:
    """A result's ``rejected`` entries in words, for a row's reason: ``"p saw q1 (3.2 px off)"``, or for a
    pixel set aside past its lens's rim (``"at": "lens"``) ``"p/front saw q1 (1.8 px past the lens's rim)"``."""
    def one(r: Mapping[str, Any]) -> str:
        if r.get("at") == "lens":
            return f"{r['observer']} saw {r['marker']} ({r['past_rim_px']:.1f} px past the lens's rim)"
        off = r.get("residual_px")
        return f"{r['observer']} saw {r['marker']} " + (f"({off:.1f} px off)" if off is not None else
                                                         "(behind the camera)")
    return ", ".join(one(r) for r in entries)


def _get_candidates(est: Estimate) -> Pose:
    c = est.__dict__["_candidates"]
    if not isinstance(c, Pose):
        c = est.__dict__["_candidates"] = c()
    return c


def _set_candidates(est: Estimate, value: Pose | Callable[[], Pose]) -> None:
    est.__dict__["_candidates"] = value


# A property over the dataclass field: ``Estimate(candidates=...)``,
# ``dataclasses.replace`` and reads all go through it.
Estimate.candidates = property(_get_candidates, _set_candidates,  # type: ignore[assignment]
                               doc="Every distinct candidate pose, best first (a Pose stack).")


def _problem(pair: PairObservations, side: np.ndarray, prow: np.ndarray, rows: np.ndarray) -> PairProblem:
    """The solver's form of the given rows (rays are computed by the solver)."""
    table = pair.table
    labels = _Labels(pair, rows)
    if table.mounts is not None:  # robots with several cameras or wide-angle lenses: rays in robot frames
        parent = pair.parent
        bearings, frames = pair_rays(table.lenses, [parent.observer[r] for r in rows.tolist()], parent.uv[rows],
                                     labels.__getitem__)
        scale = pair.sigma_scale if rows is pair.rows else parent.scales_of(rows)
        return PairProblem.trusted(side, np.ascontiguousarray(table.points[prow]), bearings, None, None, None, labels,
                                   None if scale is None else np.ascontiguousarray(scale), frames)
    if rows is pair.rows:  # the named observations: their arrays are kept on the pair
        return PairProblem.trusted(side, pair.points, None, pair.uv, table.K, table.dist, labels, pair.sigma_scale)
    scale = pair.parent.scales_of(rows)
    return PairProblem.trusted(side, table.points[prow], None, pair.parent.uv[rows], table.K, table.dist, labels,
                               None if scale is None else np.ascontiguousarray(scale))


class _Labels:
    """``observations['p']['M1']`` of row k, made only when a message needs it."""

    def __init__(self, pair: PairObservations, rows: np.ndarray):
        self.pair, self.rows = pair, rows

    def __getitem__(self, k: int) -> str:
        r = int(self.rows[k])
        return f"observations[{self.pair.parent.observer[r]!r}][{self.pair.parent.marker[r]!r}]"


def _labellings(rig: Rig, pair: PairObservations) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """(side, marker row, observation row) of the named observations, then of
    every injective labelling of the anonymous pixels with the other robot's
    markers added to them."""
    base = (pair.side, pair.points_index, pair.rows)
    if not pair.anonymous:
        yield base
        return
    robots = (pair.source, pair.target)
    index = pair.table.index
    per_side = []
    for side, rows in sorted(pair.anonymous.items()):
        other = rig.robots[robots[1 - side]]
        names = list(other.markers)
        if len(rows) > len(names):
            raise ObservationError(
                f"observations[{robots[side]!r}]: {len(rows)} anonymous markers but robot {other.name!r} has "
                f"{len(names)}"
            )
        per_side.append([[(side, index[n][1], r) for n, r in zip(perm, rows)]
                         for perm in permutations(names, len(rows))])
    total = int(np.prod([len(p) for p in per_side]))
    if total > MAX_ASSIGNMENTS:
        raise ObservationError(f"{total} possible marker identities: too many anonymous markers to try")
    for combo in product(*per_side):
        extra = [item for part in combo for item in part]
        yield tuple(np.r_[b, [e[k] for e in extra]].astype(np.int64) for k, b in enumerate(base))


def localize(rig: Any, observations: ObservationSet | Mapping[str, Any], source: str | None = None,
             target: str | None = None, *, pixel_sigma: float = 1.0, refine: bool = True, root_filter: bool = False,
             initializer: str = "minimal", confidence: float = DEFAULT_CONFIDENCE, reject_outliers: bool = True,
             scale_covariance: bool = False, allow_unverified: bool = True) -> Estimate:
    """Relative pose ``T_qp`` of robot ``source`` (p) in robot ``target``'s (q) frame.

    ``observations`` is an :class:`ObservationSet` or the SPEC's dict mapping
    each observing robot to ``{marker: (u, v)}`` raw (distorted) pixels, or
    to a list of ``(u, v)`` when the markers' identities are unknown (every
    labelling is tried and the result says whether the identity was
    ambiguous).  Where a marker has several candidate pixels the best-scored
    is used.  ``initializer`` is ``"minimal"`` (every 3-marker subset),
    ``"essential"`` (the paper's Section III-E, five or more markers) or
    ``"both"``.

    Every estimate is tested against its own noise: the squared reprojection
    residuals over ``pixel_sigma**2`` against the chi-square quantile at
    ``confidence`` with ``2n - 6`` degrees of freedom (``est.consistency``).
    When the test fails and there are five or more observations, the largest
    consistent subset is kept and the observations left out are named in
    ``est.rejected`` (``reject_outliers``); ``confidence=1`` disables the
    test (Monte Carlo studies of the estimator); when nothing consistent remains,
    :class:`~mutloc.errors.InconsistentObservationsError` is raised (it
    carries the failed estimate).  Three observations cannot be tested:
    ``est.status`` is ``"unverified"`` (with ``allow_unverified=False``,
    :class:`~mutloc.errors.UnverifiedError` instead).  For users who do not know their pixel
    noise, ``scale_covariance`` takes the covariance's noise from the observed
    residual (``sqrt(cost / dof)``, reported as ``pixel_sigma``); the test then
    uses ``pixel_sigma`` as the largest noise accepted.
    """
    try:
        return _localize(rig, observations, source, target, pixel_sigma=pixel_sigma, refine=refine,
                         root_filter=root_filter, initializer=initializer, confidence=confidence,
                         reject_outliers=reject_outliers, scale_covariance=scale_covariance,
                         allow_unverified=allow_unverified)
    except ObservationError:
        # a pixel noise pushed a little past a lens's rim: set aside and named in ``rejected``, not a refusal
        rig = load_rig(rig)
        kept, aside = set_aside_past_rim(rig, ObservationSet.from_dict(observations),
                                         positive_number(pixel_sigma, "pixel_sigma"))
        if not aside:
            raise
    est = _localize(rig, kept, source, target, pixel_sigma=pixel_sigma, refine=refine, root_filter=root_filter,
                    initializer=initializer, confidence=confidence, reject_outliers=reject_outliers,
                    scale_covariance=scale_covariance, allow_unverified=allow_unverified)
    est.rejected = aside + est.rejected
    return est


def _localize(rig: Any, observations: ObservationSet | Mapping[str, Any], source: str | None = None,
             target: str | None = None, *, pixel_sigma: float = 1.0, refine: bool = True, root_filter: bool = False,
             initializer: str = "minimal", confidence: float = DEFAULT_CONFIDENCE, reject_outliers: bool = True,
             scale_covariance: bool = False, allow_unverified: bool = True) -> Estimate:
    """:func:`localize` without setting aside pixels past a lens's rim."""
    rig = load_rig(rig)
    source, target = rig.default_pair(source, target)
    if not (type(pixel_sigma) is float and 0.0 < pixel_sigma < math.inf):  # the common case, at once
        pixel_sigma = positive_number(pixel_sigma, "pixel_sigma")
    confidence_level(confidence)
    if initializer not in ("minimal", "essential", "both"):
        raise InputError(f"initializer must be 'minimal', 'essential' or 'both', got {initializer!r}")
    observations = ObservationSet.from_dict(observations)
    if observations.has_alternatives:
        return _choose_alternatives(rig, observations, source, target, pixel_sigma=pixel_sigma, refine=refine,
                                    root_filter=root_filter, initializer=initializer, confidence=confidence,
                                    reject_outliers=reject_outliers, scale_covariance=scale_covariance,
                                    allow_unverified=allow_unverified)
    pair = observations.pair(rig, source, target)
    pair.require()
    obs = pair.parent
    results: list[tuple[float, np.ndarray, Solution, np.ndarray]] = []
    if pair.anonymous:
        errors: list[MutlocError] = []
        for side, prow, rows in _labellings(rig, pair):
            problem = _problem(pair, side, prow, rows)
            try:
                sol = _solve(problem, refine=refine, root_filter=root_filter, initializer=initializer,
                             accept=_accept(len(rows), pixel_sigma, confidence))
            except MutlocError as exc:
                errors.append(exc)
                continue
            results.append((sol.cost, prow, sol, rows))
        if not results:
            raise errors[0]
        results.sort(key=lambda r: r[0])
        cost_best, prow, sol, rows = results[0]
    else:
        prow, rows = pair.points_index, pair.rows
        solved = _problem(pair, pair.side, prow, rows)
        try:
            sol = _solve(solved, refine=refine, root_filter=root_filter,
                         initializer=initializer, accept=_accept(len(rows), pixel_sigma, confidence))
        except NoSolutionError:
            # With several cameras a false detection (another object in a camera looking away) can put every
            # pose's markers behind some camera: the largest consistent set then decides, from every
            # subset's candidates, as for a failed test.
            if pair.table.mounts is None or not reject_outliers or len(rows) <= MIN_VERIFIABLE:
                raise
            sol = None
        cost_best = math.inf if sol is None else sol.cost
    rejected: list[dict[str, Any]] = []
    kept_side = pair.side
    if sol is None:
        test, passed = None, False
    else:
        test = consistency(sol.cost, sol.n_obs, pixel_sigma, confidence)
        passed = test.passed
    if passed is False and reject_outliers and not pair.anonymous:
        problem = _problem(pair, pair.side, pair.points_index, pair.rows)
        problem.ensure_bearings()
        robust = largest_consistent_set(problem, sol if sol is not None else _candidates_only(problem),
                                        pixel_sigma, confidence)
        if robust is None and sol is None:
            raise NoSolutionError("no pose explains the observations: every solution puts a marker behind a camera, "
                                  "and no consistent subset of them was found")
        if robust is not None:
            dropped = np.setdiff1d(np.arange(len(rows)), robust.keep)
            err = observation_errors(problem, robust.solution.pose.R, robust.solution.pose.t)[0]
            rejected = [{"observer": obs.observer[int(rows[k])], "marker": obs.marker[int(rows[k])],
                         # None: the pose puts the marker behind the camera that saw it
                         "residual_px": float(np.sqrt(err[k])) if np.isfinite(err[k]) else None} for k in dropped]
            sol, prow, rows, test = robust.solution, prow[robust.keep], rows[robust.keep], robust.test
            kept_side = pair.side[robust.keep]
            cost_best, passed = sol.cost, test.passed
    n = sol.n_obs
    names = pair.names if prow is pair.points_index else pair.table.names(prow)
    ambiguous = None
    assignment = None
    if pair.anonymous:
        dof = 2 * n - 6
        gate = chi2_quantile(0.99, dof) * pixel_sigma**2 if dof > 0 else np.inf
        ambiguous = len(results) > 1 and results[1][0] <= max(gate, 1e-12)
        anon_rows = {r for rs in pair.anonymous.values() for r in rs}
        assignment = {}
        for name, r in zip(names, rows.tolist()):
            if r in anon_rows:
                assignment.setdefault(obs.observer[r], {})[name] = obs.uv[r].tolist()
    sigma_used = pixel_sigma
    if scale_covariance and test.dof > 0:
        sigma_used = float(np.sqrt(sol.cost / test.dof))
    est = Estimate(
        source=source,
        target=target,
        pose=sol.pose,
        # the solution's own array when there is nothing to scale (no copy)
        covariance=sol.information_inv if sigma_used == 1.0 else sol.covariance(sigma_used),
        pixel_sigma=sigma_used,
        reprojection_rms_px=math.sqrt(cost_best / n),
        markers_used=names,
        candidates=lambda s=sol: s.candidates,  # solved for on first read (Solution)
        consistency=test,
        rejected=rejected,
        identity_ambiguous=ambiguous,
        assignment=assignment,
    )
    if passed is False:
        raise InconsistentObservationsError(_inconsistency_message(est, pair, rows, sol, pixel_sigma), est)
    if passed and pair.table.mounts is not None and not pair.anonymous:
        # Robots with several cameras or wide-angle lenses: a far robot seen through four markers by one
        # camera fits two poses more often than not; only a unique pose is solved.
        problem = solved if rows is pair.rows else _problem(pair, kept_side, prow, rows)
        other = other_consistent_poses(problem, sol, pixel_sigma,
                                       confidence if confidence < 1.0 else DEFAULT_CONFIDENCE)
        est.alternatives = Pose.concatenate(other) if other else Pose(np.empty((0, 3, 3)),
                                                                                        np.empty((0, 3)))
        passed = None if other else passed
        if passed:
            # One pose, but is its covariance its uncertainty? Not where the cost is far from quadratic
            # within its own 3-sigma ellipsoid (a far robot through a few markers close together in one lens).
            bend = covariance_nonlinearity(problem, sol.pose, est.covariance, sigma_used)
            if bend > NONLINEARITY_LIMIT:
                est.nonlinearity = bend
                passed = None
    if passed is None and not allow_unverified:
        if est.nonlinearity is not None:
            raise UnverifiedError(
                f"{n} marker observations between {source!r} and {target!r} ({', '.join(names)}) fit one pose, but "
                f"its covariance does not describe its error: 3 sigma along its weakest direction the cost is off "
                f"the linear prediction by {_percent(est.nonlinearity)}; accept the risk with --allow-unverified "
                "(allow_unverified=True) or observe more markers", est)
        if est.alternatives is not None and len(est.alternatives):
            raise UnverifiedError(
                f"{n} marker observations between {source!r} and {target!r} ({', '.join(names)}) fit "
                f"{len(est.alternatives) + 1} different poses within their noise: nothing says which; accept "
                "the risk with --allow-unverified (allow_unverified=True) or observe more markers", est)
        k = len(est.candidates)
        fit = "a pose fits them exactly" if k == 1 else f"{k} poses fit them exactly"
        raise UnverifiedError(
            f"only {n} marker observations between {source!r} and {target!r} ({', '.join(names)}): "
            f"{fit} and nothing can verify {'it' if k == 1 else 'the one chosen'}; accept the risk "
            "with --allow-unverified (allow_unverified=True) or observe a fourth marker", est)
    return est


def _percent(x: float) -> str:
    return f"{100 * x:.0f} %" if math.isfinite(x) else "more than any bound (a marker leaves its camera's view)"


def _candidates_only(problem: PairProblem) -> Any:
    """What :func:`largest_consistent_set` reads of a first solution (its candidates) when no pose fits all
    observations: every minimal subset's distinct poses."""
    from types import SimpleNamespace

    subsets = minimal_subsets(problem.side)
    Rc = np.empty((max(len(subsets) * PER_SUBSET, 1), 3, 3))
    tc = np.empty((len(Rc), 3))
    nc = minimal_candidates_kernel(problem.side, problem.points, problem.ensure_bearings(), problem.origins, subsets,
                                   False, Rc, tc)
    return SimpleNamespace(candidates=Pose(Rc[:nc], tc[:nc]))


def _inconsistency_message(est: Estimate, pair: PairObservations, rows: np.ndarray, sol: Solution,
                           sigma: float) -> str:
    c = est.consistency
    assert c is not None
    worst = ""
    outside = pair.farthest_outside(margin=3.0 * sigma)
    if outside is not None:
        # A pixel outside its image: the suspect, whatever the fit spread its error over.
        k, px, size = outside
        r = int(pair.rows[k])
        u, v = pair.parent.uv[r].tolist()
        return (f"observations[{pair.parent.observer[r]!r}][{pair.parent.marker[r]!r}]: pixel ({u:.2f}, {v:.2f}) "
                f"is {px:.1f} px outside the {size[0]}x{size[1]} image, and the observations do not fit one pose "
                f"with {sigma:g} px noise (chi2 {c.chi2:.1f} over {c.dof} degrees of freedom, above "
                f"{c.threshold:.1f} at {100 * c.confidence:g}%): a wrong detection or a wrong camera calibration")
    problem = _problem(pair, pair.side, pair.points_index, pair.rows)
    try:
        problem.ensure_bearings()
        err = np.sqrt(observation_errors(problem, sol.pose.R, sol.pose.t)[0])
        k = int(np.argmax(err))
        r = int(pair.rows[k])
        worst = (f"; worst: observations[{pair.parent.observer[r]!r}][{pair.parent.marker[r]!r}] off by "
                 f"{err[k]:.1f} px")
    except MutlocError:
        pass
    return (f"observations between {pair.source!r} and {pair.target!r} do not fit one pose with {sigma:g} px noise "
            f"(chi2 {c.chi2:.1f} over {c.dof} degrees of freedom, above {c.threshold:.1f} at "
            f"{100 * c.confidence:g}%): a wrong detection, a wrong rig or more noise than --pixel-sigma says"
            f"{worst}")


# Combinations of candidate pixels tried at most (the rest fall back to the
# best-scored candidates and the consistent-subset search).
MAX_COMBINATIONS = 256


def _choose_alternatives(rig: Rig, obs: ObservationSet, source: str, target: str, **options: Any) -> Estimate:
    """Where a detector handed over several candidates for a marker, the
    combination the mutual geometry supports: of the combinations that pass
    the consistency test, the one the detector scored highest (then the
    smallest chi-square)."""
    groups: dict[tuple, list[int]] = {}
    for i, (o, m) in enumerate(zip(obs.observer, obs.marker)):
        groups.setdefault((o, m if m is not None else f"#{i}"), []).append(i)
    choices = [sorted(g, key=lambda i: -obs.score[i]) for g in groups.values()]
    total = int(np.prod([len(c) for c in choices]))
    best: Estimate | None = None
    best_key = (-np.inf, 0.0)
    if total <= MAX_COMBINATIONS:
        strict = dict(options, reject_outliers=False, allow_unverified=True)
        for combo in product(*choices):
            try:
                est = localize(rig, obs.take(np.array(combo)), source, target, **strict)
            except MutlocError:  # this combination fits no pose (inconsistent, or every pose puts a marker behind)
                continue
            if est.consistency is None or not est.consistency.passed:
                continue
            key = (float(np.sum(obs.score[list(combo)])), -est.consistency.chi2)
            if key > best_key:
                best, best_key = est, key
    if best is None:
        return localize(rig, obs.best(), source, target, **options)
    best.extra["combinations_tried"] = total
    return best


def localize_batch(rig: Any, frames: Sequence[ObservationSet | Mapping[str, Any]], source: str | None = None,
                   target: str | None = None, **options: Any) -> list[Estimate | MutlocError]:
    """:func:`localize` over many frames (or pairs' observations) in one
    call: per frame its :class:`Estimate`, or the typed error that says why
    that frame has none (one bad frame does not stop the batch)."""
    rig = load_rig(rig)
    source, target = rig.default_pair(source, target)
    out: list[Estimate | MutlocError] = []
    for frame in frames:
        try:
            out.append(localize(rig, frame, source, target, **options))
        except MutlocError as exc:
            out.append(exc)
    return out


def _accept(n: int, sigma: float, confidence: float) -> float | None:
    """The cost at which the first minimal subset's optimum is kept without
    solving the others: one that passes the consistency test (at the default
    confidence when the test is disabled, so the shortcut never keeps a
    misfit the full search would improve on)."""
    dof = 2 * n - 6
    if dof <= 0:
        return None
    return chi2_quantile(confidence if confidence < 1.0 else DEFAULT_CONFIDENCE, dof) * sigma * sigma


def _solve(obs: PairProblem, *, refine: bool, root_filter: bool, initializer: str,
           accept: float | None = None) -> Solution:
    if initializer == "minimal":
        return estimate(obs, refine=refine, root_filter=root_filter, accept=accept)
    from .core.essential import essential_candidates

    extra = essential_candidates(obs.side, obs.points, obs.ensure_bearings())
    return estimate(obs, refine=refine, root_filter=root_filter, extra_candidates=extra,
                    use_minimal=initializer != "essential", accept=accept)


def solve_bearings(bearings_p: Any, points_q: Any, bearings_q: Any, points_p: Any, *,
                   origins_p: Any = None, origins_q: Any = None, refine: bool = True,
                   root_filter: bool = False) -> Pose:
    """Every candidate ``T_qp`` from unit rays, best first (a :class:`Pose` stack).

    ``bearings_p`` (n, 3): rays in p's frame towards q's markers at
    ``points_q`` (n, 3) in q's frame; likewise ``bearings_q`` (m, 3) and
    ``points_p`` (m, 3); ``n + m >= 3``, either may be empty.  With more than
    three rays the first pose is refined on the tangent-plane ray error.

    ``origins_p`` (n, 3) and ``origins_q`` (m, 3): where each ray starts in
    its robot's frame (robots with several cameras: each camera's centre);
    default every ray from its robot's origin.  Minimal subsets whose rays of
    one robot leave several centres are solved by the generalized P3P.
    """
    arrs = []
    for name, a in (("bearings_p", bearings_p), ("points_q", points_q), ("bearings_q", bearings_q),
                    ("points_p", points_p), ("origins_p", origins_p), ("origins_q", origins_q)):
        if a is None and name.startswith("origins"):  # every ray from its robot's origin
            a = np.zeros((len(arrs[0] if name == "origins_p" else arrs[2]), 3))
        try:
            x = np.asarray(a if a is not None else np.empty((0, 3)), dtype=float)
        except (TypeError, ValueError, OverflowError):
            raise InputError(f"{name} must be an array of finite numbers of shape (n, 3)") from None
        if x.size == 0:
            x = x.reshape(0, 3)
        if x.ndim != 2 or x.shape[1] != 3:
            raise InputError(f"{name} must have shape (n, 3), got {x.shape}")
        arrs.append(x)
    bp, pq, bq, pp, op, oq = arrs
    if bp.shape[0] != pq.shape[0] or bp.shape[0] != op.shape[0]:
        raise InputError(f"bearings_p has {bp.shape[0]} rows but points_q has {pq.shape[0]} and origins_p "
                         f"{op.shape[0]}")
    if bq.shape[0] != pp.shape[0] or bq.shape[0] != oq.shape[0]:
        raise InputError(f"bearings_q has {bq.shape[0]} rows but points_p has {pp.shape[0]} and origins_q "
                         f"{oq.shape[0]}")
    obs = PairProblem(
        side=np.r_[np.zeros(len(bp), np.int64), np.ones(len(bq), np.int64)],
        points=np.vstack([pq, pp]),
        bearings=np.vstack([bp, bq]),
    )
    origins = np.vstack([op, oq])
    if not np.all(np.isfinite(origins)):
        raise InputError("origins_p and origins_q must be finite")
    if np.any(origins):  # rays from several centres: each ray's unit tangent frame and origin
        frames = np.empty((len(origins), 4, 3))
        basis = np.empty((len(origins), 3, 3))
        tangent_bases(obs.bearings, basis)
        frames[:, :3] = basis
        frames[:, 3] = origins
        obs.frames = frames
    for s, pts in ((0, pq), (1, pp)):
        for i in range(len(pts)):
            for j in range(i + 1, len(pts)):
                if np.linalg.norm(pts[i] - pts[j]) < 1e-9:
                    from .errors import DegenerateGeometryError

                    raise DegenerateGeometryError(f"{'points_q' if s == 0 else 'points_p'}: markers {i} and {j} coincide")
    sol = estimate(obs, refine=refine, root_filter=root_filter)
    if len(obs.side) == 3 or not refine:
        return sol.candidates
    best = sol.pose
    cands = sol.candidates
    rest = cands[cands.translation_error(best) > 1e-9 * (1 + np.linalg.norm(best.t))]
    return Pose.concatenate([best, rest])

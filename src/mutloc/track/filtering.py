"""Frame by frame, what a track reports: each frame's observations either
localized on their own (``--filter none``) or folded into the
constant-velocity filter of :mod:`mutloc.core.filter` (``--filter cv``).

With the filter (SPEC "Filtered tracking"): the track starts from the first
frame ``localize`` solves (four or more markers, consistent with their
noise); after that every frame updates it -- ``solved`` with three or more
markers consistent with the track (the prior confirms three-marker frames),
``partial`` with one or two, ``predicted`` with none, ``rejected`` (with the
predicted pose and the reason) when the observations contradict the track.
After ``reinit_after`` rejected frames in a row, a frame that ``localize``
solves on its own restarts the track (the track had gone wrong, e.g. a
robot was carried); when the predicted uncertainty grows past
``lost_sigma_t``/``lost_sigma_r_deg`` the track is lost and restarts the
same way.  A team tracker is one :class:`PairTracker` per robot against the
reference.

Blinking lights are rarely all on together, so a frame ``localize`` solves
on its own (four measured markers) may be seconds away.  A frame with exactly
three measured markers (``unverified``) therefore starts a *tentative*
track: its frames keep their per-frame statuses (nothing is reported from
it) until a frame of three markers, at least one of them not among the
starting three and predicted sharply (``CONFIRM_SPREAD``), is consistent
with it -- two different marker sets, each fixing the pose on its own,
agree through the motion prior.  From that frame on the track is confirmed
and reports as above; with the fixed-lag smoother, so do its tentative
frames within the lag that the frames after them verify (see
:mod:`.hindsight`).  A tentative track that any frame contradicts is
dropped, and a frame of four or more markers decides for itself: solved,
it confirms the track where it agrees with it as above, else starts a new
one; not solved, the tentative track goes (it may share the frame's bad
detection and so agree with it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from ..api import Estimate, localize
from ..core.consistency import DEFAULT_CONFIDENCE
from ..core.estimate import PairProblem
from ..core.filter import ConstantVelocityFilter, FilterState, FilterUpdate, MotionNoise, rts_gains, rts_smooth
from ..core.observations import MIN_OBSERVATIONS, PairObservations
from ..core.pose import Pose
from ..core.rig import Rig
from ..errors import InconsistentObservationsError, InputError, MutlocError, positive_number
from .hindsight import TentativeFrames
from .status import FrameStatus

if TYPE_CHECKING:
    from .tracker import TrackRow

__all__ = ["DEFAULT_SMOOTH_LAG", "FILTERS", "FilterOptions", "PairTracker", "solve_row", "lost_reason",
           "pair_problem"]

#: A tentative track is confirmed only by markers it predicted within this
#: many pixel sigmas (1-sigma, largest axis): a sharper prediction than any
#: plausible wrong start could meet.
CONFIRM_SPREAD = 5.0

#: ``--filter`` choices: the constant-velocity filter, or every frame on its own.
FILTERS = ("cv", "none")
#: Frames after each frame that inform its reported pose by default (1/3 s
#: at 30 fps): the inputs are recorded, and on the issue's sequences this
#: fixed-lag smoother halves the causal filter's error (README "Filtered tracking").
DEFAULT_SMOOTH_LAG = 10


@dataclass(frozen=True)
class FilterOptions:
    """How a track is filtered (documented defaults).

    ``kind``: ``"cv"`` (constant velocity) or ``"none"``; ``noise``: the
    motion model's :class:`~mutloc.core.filter.MotionNoise`;
    ``reinit_after``: rejected frames in a row after which a frame solved
    on its own restarts the track; ``lost_sigma_t`` (m) and
    ``lost_sigma_r_deg``: a predicted 1-sigma beyond these loses the track;
    ``smooth_lag``: frames after each frame that also inform its reported
    pose (fixed-lag RTS smoothing; 0 = the causal filter's pose; None, the
    default: ``DEFAULT_SMOOTH_LAG`` with the filter, 0 without);
    ``measure_noise``: the gain uses the detections' measured noise when it
    is clearly below ``pixel_sigma`` (see
    :attr:`~mutloc.core.filter.ConstantVelocityFilter.gain_sigma`).
    """

    kind: str = "cv"
    noise: MotionNoise = field(default_factory=MotionNoise)
    reinit_after: int = 3
    lost_sigma_t: float = 0.5
    lost_sigma_r_deg: float = 20.0
    smooth_lag: int | None = None
    measure_noise: bool = True

    def __post_init__(self) -> None:
        if self.kind not in FILTERS:
            raise InputError(f"filter must be one of {', '.join(FILTERS)}, got {self.kind!r}")
        if self.smooth_lag is None:
            object.__setattr__(self, "smooth_lag", DEFAULT_SMOOTH_LAG if self.kind == "cv" else 0)
        if not (isinstance(self.reinit_after, int) and self.reinit_after >= 1):
            raise InputError(f"reinit_after must be an integer >= 1, got {self.reinit_after!r}")
        if not (isinstance(self.smooth_lag, int) and self.smooth_lag >= 0):
            raise InputError(f"smooth_lag must be an integer >= 0 (frames), got {self.smooth_lag!r}")
        if self.smooth_lag and self.kind != "cv":
            raise InputError("smoothing (--smooth-lag) needs the filter (--filter cv)")
        positive_number(self.lost_sigma_t, "lost_sigma_t")
        positive_number(self.lost_sigma_r_deg, "lost_sigma_r_deg")


def solve_row(row: "TrackRow", rig: Rig, source: str, target: str, pixel_sigma: float, confidence: float) -> None:
    """Localize the row's observations on their own; set its status, reason and estimate.

    Where too few markers were measured but blinking lights that are off
    have predicted positions, the frame is localized with those too: the
    pose is reported, always ``unverified`` (a prediction cannot expose a
    wrong pose)."""
    _solve_observations(row, rig, source, target, pixel_sigma, confidence)
    if row.status != FrameStatus.TOO_FEW or not any(d.predicted for d in (row.detections or {}).values()):
        return
    from .frames import observations_of

    attempt = replace(row, reason="", estimate=None,
                      observations=observations_of(row.detections, row.t, include_predicted=True))
    _solve_observations(attempt, rig, source, target, pixel_sigma, confidence)
    if attempt.estimate is not None:
        n_pred = sum(len(d.predicted) for d in row.detections.values())
        row.estimate, row.status = attempt.estimate, FrameStatus.UNVERIFIED
        row.reason = (f"{row.reason}; localized with {n_pred} predicted position(s) of lights that are off "
                      "(unverified)")


def _solve_observations(row: "TrackRow", rig: Rig, source: str, target: str, pixel_sigma: float,
                        confidence: float) -> None:
    obs = row.observations
    assert obs is not None
    try:
        pair = obs.pair(rig, source, target)
        if pair.count < MIN_OBSERVATIONS:
            row.status = FrameStatus.TOO_FEW
            row.reason = f"{pair.count} markers seen ({_seen(pair, source, target)})"
            return
        row.estimate = localize(rig, obs, source, target, pixel_sigma=pixel_sigma, confidence=confidence)
        row.status = FrameStatus.SOLVED if row.estimate.status == "solved" else FrameStatus.UNVERIFIED
        if row.estimate.rejected:
            row.reason = "dropped " + ", ".join(f"{r['observer']} saw {r['marker']} ({r['residual_px']:.1f} px off)"
                                                for r in row.estimate.rejected)
    except InconsistentObservationsError as exc:
        row.status = FrameStatus.REJECTED
        row.reason = " ".join(str(exc).split())
    except MutlocError as exc:
        row.status = FrameStatus.FAILED
        row.reason = " ".join(str(exc).split())


def _seen(pair: PairObservations, source: str, target: str) -> str:
    obs = pair.parent
    seen = {r: sorted(m or "?" for o, m in zip(obs.observer, obs.marker) if o == r) for r in (source, target)}
    return ", ".join(f"{r}: {v}" for r, v in seen.items())


class PairTracker:
    """Turns each frame (a :class:`~mutloc.track.tracker.TrackRow` with its
    observations) into its reported status and pose, in time order."""

    def __init__(self, rig: Rig, source: str, target: str, *, pixel_sigma: float = 1.0,
                 confidence: float = DEFAULT_CONFIDENCE, options: FilterOptions | None = None) -> None:
        self.rig, self.source, self.target = rig, source, target
        self.pixel_sigma = positive_number(pixel_sigma, "pixel_sigma")
        self.confidence = confidence
        self.options = options if options is not None else FilterOptions()
        self.filter = ConstantVelocityFilter(self.options.noise, pixel_sigma, confidence,
                                             measure_noise=self.options.measure_noise)
        self.rejections = 0
        self._restarted = False
        #: While the track is tentative: the markers of the three-marker frame that started it.
        self._tentative: frozenset[str] | None = None
        #: ... and its frames since, reported again once it is confirmed (see .hindsight).
        self._tentative_frames = TentativeFrames()
        #: When a list: per frame, (prediction, state after the frame, row) while the
        #: track runs, None where it (re)starts or is lost -- for smoothing.
        self.history: list[tuple[FilterState, FilterState, Any] | None] | None = \
            [] if self.options.smooth_lag > 0 and self.filtering else None
        #: Every row filtered, aligned with ``history`` (for the hindsight checks).
        self._stepped: list[Any] = []

    @property
    def filtering(self) -> bool:
        return self.options.kind == "cv"

    def step(self, row: "TrackRow") -> None:
        """Set ``row``'s status, reason and estimate from its observations
        (rows without observations -- unpaired, corrupt -- are left alone)."""
        if row.observations is None:
            return
        if not self.filtering:
            solve_row(row, self.rig, self.source, self.target, self.pixel_sigma, self.confidence)
            return
        if self.filter.state is not None and row.t < self.filter.state.time:
            raise InputError(f"frame at {row.t} s comes before the previous one ({self.filter.state.time} s)")
        if self.history is not None:
            self._stepped.append(row)
        lost = ""
        if self.filter.state is not None:
            state = self.filter.predict(row.t)
            lost = self._lost(state)
            if lost:
                self.filter.state = None
        if self.filter.state is None:
            self._restart(row, lost)
            self._record(None)
            return
        self._restarted = False
        try:
            if self._tentative is not None:
                self._tentative_step(row, state)
            else:
                self._filtered_step(row, state)
        finally:
            self._record(None if self._restarted or self.filter.state is None or self._tentative is not None
                         else (state, self.filter.state, row))

    def _record(self, entry: tuple[FilterState, FilterState, Any] | None) -> None:
        if self.history is not None:
            self.history.append(entry)

    def segments(self) -> list[tuple[int, int]]:
        """``(first, end)`` frame ranges of ``history`` in which the track ran
        without a restart or loss (what a smoother may span)."""
        out, k, hist = [], 0, self.history or []
        while k < len(hist):
            if hist[k] is None:
                k += 1
                continue
            j = k
            while j < len(hist) and hist[j] is not None:
                j += 1
            out.append((k, j))
            k = j
        return out

    def finish(self) -> None:
        """With ``smooth_lag``: replace each filtered row's pose and covariance
        by the fixed-lag smoothed ones (the frame and the ``smooth_lag``
        frames after it in the same uninterrupted track) -- what a fixed-lag
        smoother would report ``smooth_lag`` frames late."""
        lag = self.options.smooth_lag
        if not lag or not self.history:
            return
        hist = self.history
        self._tentative_frames.report(self, hist, self._stepped, lag)
        for k, j in self.segments():
            priors, posts = [h[0] for h in hist[k:j]], [h[1] for h in hist[k:j]]
            gains = rts_gains(priors, posts)
            for i in range(j - k):
                state = rts_smooth(priors[i:i + lag + 1], posts[i:i + lag + 1], gains[i:i + lag])[0]
                row = hist[k + i][2]
                if row.estimate is not None:
                    row.estimate = replace(row.estimate, pose=state.pose, covariance=state.pose_covariance.copy(),
                                           candidates=Pose.concatenate([state.pose]),
                                           extra=dict(row.estimate.extra, smooth_lag=lag,
                                                      velocity=state.velocity.tolist()))

    def _filtered_step(self, row: "TrackRow", state: FilterState) -> None:
        try:
            obs = row.observations
            if obs.has_alternatives:
                obs = self._nearest_candidates(obs, state.pose)
            pair = obs.pair(self.rig, self.source, self.target)
        except MutlocError as exc:
            row.status = FrameStatus.FAILED
            row.reason = " ".join(str(exc).split())
            return
        if len(pair.rows) == 0:
            row.status = FrameStatus.PREDICTED
            row.reason = "no markers seen" if pair.count == 0 else \
                f"{pair.count} markers of unknown identity (the filter needs named markers)"
            row.estimate = self._estimate(state, [], 0.0, None)
            return
        problem = self.problem(pair)
        upd = self.filter.update(problem)
        if upd.accepted:
            self.rejections = 0
            self._accepted(row, problem, upd)
            return
        self.rejections += 1
        if self.rejections >= self.options.reinit_after:
            restarted = self._restart(row, f"{self.rejections} frames in a row inconsistent with the track",
                                      keep_failure=False)
            if restarted:
                return
        row.status = FrameStatus.REJECTED
        row.reason = upd.reason
        row.estimate = self._estimate(upd.state, [], upd.rms_px, upd.test)

    # -- internals ------------------------------------------------------------

    def _tentative_step(self, row: "TrackRow", state: FilterState) -> None:
        """Update a tentative track with the row; the row reports its
        per-frame result unless this frame confirms the track."""
        if self._measured(row) > MIN_OBSERVATIONS:
            # Four or more markers judge themselves: solved, and consistent
            # with the track where it predicted them sharply, the frame
            # confirms the track; solved but not that, it starts a new one;
            # inconsistent, the tentative track (which may share the bad
            # detection, and so agree with it) goes too.
            alone = _copy_row(row)
            solve_row(alone, self.rig, self.source, self.target, self.pixel_sigma, self.confidence)
            if alone.status != FrameStatus.SOLVED or not self._confirm(row, state, _copy_row(row)):
                self.filter.state, self._tentative = None, None
                self._restart(row, "")
            return
        trial = _copy_row(row)
        if self._confirm(row, state, trial):
            return
        if trial.status in (FrameStatus.REJECTED, FrameStatus.FAILED) or self.filter.state is None:
            self.filter.state, self._tentative = None, None
            self._restart(row, "")
            return
        if self.history is not None:
            self._tentative_frames.add(len(self.history), row, trial, state, self.filter.state)
        solve_row(row, self.rig, self.source, self.target, self.pixel_sigma, self.confidence)

    def _confirm(self, row: "TrackRow", state: FilterState, trial: "TrackRow") -> bool:
        """Filter ``trial`` (a copy of ``row``) into the tentative track; when
        it confirms the track, report ``row`` (and the tentative frames, see
        :mod:`.hindsight`) as the confirmed track does and return True."""
        self._filtered_step(trial, state)
        used = set(trial.estimate.markers_used) if trial.estimate is not None else set()
        new = used - self._tentative
        # The new markers must have been predicted sharply: a wrong start
        # (three markers fit any one bad detection exactly) is exposed only
        # where the track's prediction could have missed them.  Every
        # measured marker must agree (none dropped).
        spread = max((self.spread_px(state, m) for m in new), default=math.inf)
        if (trial.status != FrameStatus.SOLVED or spread > CONFIRM_SPREAD * self.pixel_sigma
                or len(used) < self._measured(row)):
            return False
        started = ", ".join(sorted(self._tentative))
        self._tentative = None
        row.status, row.estimate = trial.status, trial.estimate
        note = (f"track confirmed: {', '.join(sorted(used))} agree with the track started on {started} "
                f"(new markers predicted within {spread:.1f} px)")
        row.reason = f"{note}; {trial.reason}" if trial.reason else note
        if self.history is not None:
            self._tentative_frames.confirm(len(self.history), self.options.smooth_lag, row.t)
        return True

    def _accepted(self, row: "TrackRow", problem: PairProblem, upd: FilterUpdate) -> None:
        names = [problem.labels[k] for k in upd.used.tolist()]
        row.status = FrameStatus.SOLVED if len(upd.used) >= MIN_OBSERVATIONS else FrameStatus.PARTIAL
        if len(upd.dropped):
            row.reason = "dropped " + ", ".join(
                f"{problem.labels[k]} ({upd.residuals_px[k]:.1f} px off)" for k in upd.dropped.tolist())
        row.estimate = self._estimate(upd.state, [_marker_of(n) for n in names], upd.rms_px, upd.test)

    def _restart(self, row: "TrackRow", why: str, keep_failure: bool = True) -> bool:
        """Localize the row on its own; a solved frame (re)starts the track, a
        frame of three measured markers starts a tentative one.  Returns
        whether it did; with ``keep_failure`` the row keeps the per-frame
        result either way."""
        self._tentative_frames.clear()
        trial = row if keep_failure else _copy_row(row)
        solve_row(trial, self.rig, self.source, self.target, self.pixel_sigma, self.confidence)
        # Only a frame solved on measured markers alone starts a track: four
        # positions that include predicted lights can pass their test and
        # still be centimetres off, and later three-marker frames would then
        # be called solved against a wrong track.
        started = trial.status == FrameStatus.SOLVED and trial.estimate is not None
        # Three measured markers (never predicted ones) start a tentative track.
        tentative = (not started and trial.status == FrameStatus.UNVERIFIED and trial.estimate is not None
                     and self._measured(trial) >= MIN_OBSERVATIONS)
        self._tentative = frozenset(trial.estimate.markers_used) if tentative else None
        if started or tentative:
            est = trial.estimate
            self.filter.reset(row.t, est.pose, est.covariance)
            self.rejections = 0
            self._restarted = True
            if tentative and self.history is not None:
                # The starting frame is a tentative frame like those after
                # it: the frames after it may verify it in hindsight (the
                # backward track that does is independent of it).
                first = _copy_row(trial)
                first.status = FrameStatus.SOLVED
                first.reason = "started the track on " + ", ".join(sorted(self._tentative))
                first.estimate = self._estimate(self.filter.state, list(est.markers_used),
                                                est.reprojection_rms_px, est.consistency)
                self._tentative_frames.add(len(self.history), row, first, self.filter.state, self.filter.state,
                                           start=True)
            if trial is not row:
                row.status, row.estimate, row.reason = trial.status, trial.estimate, trial.reason
        if why and (started or tentative or keep_failure):
            note = f"track {'restarted' if started else 'restarted tentatively' if tentative else 'lost'}: {why}"
            row.reason = f"{note}; {row.reason}" if row.reason else note
        return started or tentative

    def spread_px(self, state: FilterState, marker: str) -> float:
        """1-sigma (px, largest axis) of where ``state`` predicts ``marker``
        in its observer's image (unscented, from the pose covariance)."""
        for observer, other, inverse in ((self.target, self.source, False), (self.source, self.target, True)):
            if marker in self.rig.robot(other).markers:
                break
        else:
            return math.inf
        X = self.rig.robot(other).markers[marker].position
        cam = self.rig.robot(observer).camera
        P = state.pose_covariance
        try:
            L = np.linalg.cholesky(0.5 * (P + P.T) + 1e-18 * np.eye(6)) * math.sqrt(6.0)
        except np.linalg.LinAlgError:
            return math.inf
        pix = []
        for col in np.concatenate([L.T, -L.T]):
            T = Pose(Pose.from_rotvec(col[:3], np.zeros(3)).R @ state.pose.R, state.pose.t + col[3:])
            pix.append(cam.project((T.inverse() if inverse else T).apply(X)))
        d = np.asarray(pix, float)
        if not np.all(np.isfinite(d)):
            return math.inf
        d -= d.mean(axis=0)
        return float(math.sqrt(max(np.linalg.eigvalsh(d.T @ d / len(d)).max(), 0.0)))

    def _measured(self, row: "TrackRow") -> int:
        """Named markers measured (not predicted) in the row."""
        try:
            return len(row.observations.pair(self.rig, self.source, self.target).rows)
        except MutlocError:
            return 0

    def _nearest_candidates(self, obs: Any, pose: Pose) -> Any:
        """Where a detector handed over several candidates for a marker, the
        one nearest its predicted pixel (the track decides, not the score)."""
        best: dict[tuple, tuple[float, int]] = {}
        for i, (o, m) in enumerate(zip(obs.observer, obs.marker)):
            key = (o, m if m is not None else f"#{i}")
            one = obs.take(np.array([i])).pair(self.rig, self.source, self.target)
            err = float(self.filter.residuals(self.problem(one), pose)[0]) if len(one.rows) else 0.0
            if key not in best or err < best[key][0]:
                best[key] = (err, i)
        return obs.take(np.array(sorted(i for _, i in best.values()), dtype=np.int64))

    def _lost(self, state: FilterState) -> str:
        return lost_reason(state, self.options)

    def problem(self, pair: PairObservations) -> PairProblem:
        """The named observations of a frame in the filter's form (labels "p saw M1")."""
        return pair_problem(pair)

    def _estimate(self, state: FilterState, markers: list[str], rms: float, test: Any) -> Estimate:
        return Estimate(source=self.source, target=self.target, pose=state.pose,
                        covariance=state.pose_covariance.copy(), pixel_sigma=self.pixel_sigma,
                        reprojection_rms_px=float(rms), markers_used=markers,
                        candidates=Pose.concatenate([state.pose]), consistency=test,
                        extra={"velocity": state.velocity.tolist(), "filter": self.options.kind})


def pair_problem(pair: PairObservations) -> PairProblem:
    """The named observations of a pair in the filter's form (labels "p saw M1")."""
    table = pair.table
    obs = pair.parent
    rows = pair.rows
    labels = [f"{obs.observer[r]} saw {obs.marker[r]}" for r in rows.tolist()]
    return PairProblem.trusted(pair.side, np.ascontiguousarray(table.points[pair.points_index]), None,
                               np.ascontiguousarray(obs.uv[rows]), table.K, table.dist, labels)


def lost_reason(state: FilterState, options: FilterOptions) -> str:
    """Why a predicted state has lost its track (its 1-sigma beyond the
    options' limits), or "" while it holds."""
    d = np.diag(state.pose_covariance)
    st = math.sqrt(max(d[3:6].max(), 0.0))
    sr = math.degrees(math.sqrt(max(d[0:3].max(), 0.0)))
    o = options
    if st > o.lost_sigma_t or sr > o.lost_sigma_r_deg:
        return (f"predicted sigma {st:.2f} m / {sr:.1f} deg beyond {o.lost_sigma_t:g} m / "
                f"{o.lost_sigma_r_deg:g} deg")
    return ""


def _marker_of(label: str) -> str:
    return label.rsplit(" saw ", 1)[-1]


def _copy_row(row: "TrackRow") -> "TrackRow":
    return replace(row, reason="", estimate=None)

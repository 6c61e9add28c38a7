"""A frame on its own, and the limits of a track (used by the tracker,
:mod:`.team`, and its options, :mod:`.filtering`).

:func:`solve_row` localizes one row's observations by themselves (with the
predicted positions of lights that are off where too few markers were
measured: then always ``unverified``); :func:`lost_reason` says when a
predicted state has lost its track; :data:`CONFIRM_SPREAD` is how sharply a
track must have predicted markers before they may confirm it.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np

from ..api import localize, rejected_text
from ..core.observations import MIN_OBSERVATIONS, PairObservations
from ..core.rig import Rig
from ..detect.base import observations_of
from ..errors import InconsistentObservationsError, MutlocError
from .status import FrameStatus

if TYPE_CHECKING:
    from ..core.filter import FilterState
    from .rows import TrackRow

__all__ = ["CONFIRM_SPREAD", "solve_row", "lost_reason"]

#: A tentative track is confirmed only by markers it predicted within this
#: many pixel sigmas (1-sigma, largest axis): a sharper prediction than any
#: plausible wrong start could meet.
CONFIRM_SPREAD = 5.0

def solve_row(row: "TrackRow", rig: Rig, source: str, target: str, pixel_sigma: float, confidence: float) -> None:
    """Localize the row's observations on their own; set its status, reason and estimate.

    Where too few markers were measured but blinking lights that are off
    have predicted positions, the frame is localized with those too: the
    pose is reported, always ``unverified`` (a prediction cannot expose a
    wrong pose)."""
    _solve_observations(row, rig, source, target, pixel_sigma, confidence)
    if row.status != FrameStatus.TOO_FEW or not any(d.predicted for d in (row.detections or {}).values()):
        return
    attempt = replace(row, reason="", estimate=None,
                      observations=observations_of(row.detections, row.t,
                                                   include_predicted=True).with_sigma_scale(None))
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
            row.reason = "dropped " + rejected_text(row.estimate.rejected)
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


def lost_reason(state: "FilterState", options: Any) -> str:
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

"""Is an estimate consistent with its own noise?  The chi-square test.

With isotropic Gaussian detection noise of ``sigma`` pixels, the refined
pose's sum of squared reprojection residuals over ``n`` observations, divided
by ``sigma**2``, follows a chi-square distribution with ``2n - 6`` degrees of
freedom (two measured coordinates per observation, six pose parameters
estimated).  A value above its ``confidence`` quantile says the observations
do not fit one pose with that noise: a wrong detection, a wrong rig, or noise
larger than stated.  Three observations leave no degree of freedom: every
pose that fits fits exactly, and nothing can be verified.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

__all__ = ["Consistency", "chi2_quantile", "consistency", "DEFAULT_CONFIDENCE", "same_pose"]

#: Confidence of the test: a correct estimate fails it with probability 1 - this.
DEFAULT_CONFIDENCE = 0.99


@lru_cache(maxsize=1024)
def chi2_quantile(confidence: float, dof: int) -> float:
    """The ``confidence`` quantile of chi-square with ``dof`` degrees of freedom (cached)."""
    from scipy.stats import chi2

    return float(chi2.ppf(confidence, dof))


@dataclass(frozen=True)
class Consistency:
    """The test's figures: ``chi2`` (squared residuals over sigma squared),
    ``dof``, ``threshold`` (its quantile at ``confidence``); ``passed`` is
    None when ``dof`` is 0 (unverifiable)."""

    chi2: float
    dof: int
    confidence: float
    threshold: float

    @property
    def passed(self) -> bool | None:
        if self.dof <= 0:
            return None
        return self.chi2 <= self.threshold

    @property
    def p_value(self) -> float | None:
        """Probability of a chi-square this large or larger for a correct estimate."""
        if self.dof <= 0:
            return None
        from scipy.stats import chi2

        return float(chi2.sf(self.chi2, self.dof))

    def to_dict(self) -> dict[str, Any]:
        return {"chi2": self.chi2, "dof": self.dof, "confidence": self.confidence,
                "threshold": None if self.dof <= 0 else self.threshold, "passed": self.passed}


def consistency(cost_px2: float, n_obs: int, sigma: float, confidence: float = DEFAULT_CONFIDENCE) -> Consistency:
    """The test for a refined estimate with squared-residual sum ``cost_px2``
    (pixels squared) over ``n_obs`` observations and noise ``sigma`` pixels."""
    dof = 2 * n_obs - 6
    threshold = chi2_quantile(confidence, dof) if dof > 0 else math.inf
    return Consistency(float(cost_px2) / sigma**2, dof, confidence, threshold)


def same_pose(a: Any, Pa: Any, b: Any, Pb: Any, confidence: float) -> bool:
    """Whether two independent estimates of one pose (``a``, ``b`` with 6x6
    covariances ``Pa``, ``Pb``, SPEC order) agree: the Mahalanobis distance
    of their difference under the sum of their covariances within the
    chi-square quantile with 6 degrees of freedom (always, at confidence 1)."""
    import numpy as np

    from .geometry import so3_log

    if confidence >= 1.0:
        return True
    e = np.r_[so3_log(a.R @ b.R.T), a.t - b.t]
    S = np.asarray(Pa, float) + np.asarray(Pb, float)
    try:
        m = float(e @ np.linalg.solve(0.5 * (S + S.T), e))
    except np.linalg.LinAlgError:
        return False
    return m <= chi2_quantile(confidence, 6)

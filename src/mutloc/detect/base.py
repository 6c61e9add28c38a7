"""What every detector returns.

Images are NumPy arrays in OpenCV's layout: ``uint8`` BGR ``(H, W, 3)`` (as
``cv2.imread`` gives them) or grayscale ``(H, W)``.  Pixels follow the SPEC:
``(u, v)`` with ``(0, 0)`` the centre of the top-left pixel, raw (distorted).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from ..core.observations import ObservationSet
from ..errors import InputError

__all__ = ["Detection", "DetectionResult", "as_bgr", "observations_of"]


@dataclass
class Detection:
    """One marker found in an image."""

    marker: str
    uv: np.ndarray
    score: float = 1.0
    # Tag corners (4, 2) in OpenCV's corner order, when the detector has them.
    corners: np.ndarray | None = None
    info: dict[str, Any] = field(default_factory=dict)
    #: The position is carried over from earlier images (a blinking light that
    #: is off now), not measured in this one: it cannot verify a pose.
    predicted: bool = False
    #: Quality, where the detector measures it: the share (0..1) of the
    #: marker's outline seen unhidden ...
    visible_fraction: float | None = None
    #: ... and the RMS residual (pixels) of the outline's fit.
    residual_px: float | None = None
    #: The position's noise relative to a whole marker's (1): a partly hidden
    #: ball's centre, fitted on part of its rim, is known less well.  It goes
    #: with the pixel into :class:`~mutloc.ObservationSet` (``sigma_scale``), so
    #: the pose weighs it less and its covariance grows.
    sigma_scale: float = 1.0

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"uv": [float(self.uv[0]), float(self.uv[1])], "score": float(self.score)}
        if self.predicted:
            d["predicted"] = True
        if self.corners is not None:
            d["corners"] = np.asarray(self.corners, float).tolist()
        for what in ("visible_fraction", "residual_px"):
            if getattr(self, what) is not None:
                d[what] = float(getattr(self, what))
        if self.sigma_scale != 1.0:
            d["sigma_scale"] = float(self.sigma_scale)
        if self.info:
            d["info"] = self.info
        return d


@dataclass
class DetectionResult:
    """The markers one robot's camera saw in one image, and those it did not."""

    detections: dict[str, Detection] = field(default_factory=dict)
    missing: list[str] = field(default_factory=list)
    #: Why each missing marker is missing, a short code: ``"not_found"`` (no
    #: candidate in the image), ``"rejected"`` (candidates failed a quality
    #: check), ``"occluded"``, ``"too_small"``, ``"ambiguous"``; a detector may
    #: append detail after a colon.  Per-detection quality figures (decision
    #: margin, edge residual, visible fraction) are in ``Detection.info``.
    missing_reasons: dict[str, str] = field(default_factory=dict)
    #: Other candidates for a detected marker where the detector is unsure
    #: (scored, best first); the localizer picks what the geometry supports.
    alternatives: dict[str, list[Detection]] = field(default_factory=dict)

    def observations(self, observer: str, time: float | None = None, *,
                     include_predicted: bool = False) -> ObservationSet:
        """What ``observer``'s camera measured, as an :class:`ObservationSet`
        (the detector's score and ``sigma_scale`` travel with each pixel).  Predicted positions
        (a blinking light that is off) are not measurements and are left out:
        they would count earlier frames twice and cannot expose a wrong pose
        (``include_predicted`` keeps them, e.g. to start a track)."""
        dets = [d for d in self.detections.values() if include_predicted or not d.predicted]
        dets += [a for alts in self.alternatives.values() for a in alts]
        uv = np.array([d.uv for d in dets], dtype=float).reshape(-1, 2)
        return ObservationSet([observer] * len(dets), [d.marker for d in dets], uv, time,
                              [float(d.score) for d in dets], [float(d.sigma_scale) for d in dets])

    def copy(self) -> "DetectionResult":
        """A copy whose dicts and lists can be changed without changing this one (the detections are shared)."""
        return DetectionResult(dict(self.detections), list(self.missing), dict(self.missing_reasons),
                               {n: list(a) for n, a in self.alternatives.items()})

    @property
    def predicted(self) -> list[str]:
        """The markers whose positions are predicted from earlier images, not measured in this one."""
        return [n for n, d in self.detections.items() if d.predicted]

    def pixels(self) -> dict[str, tuple[float, float]]:
        """``{marker: (u, v)}``: one observer's entry of the SPEC's observations dict."""
        return {name: (float(d.uv[0]), float(d.uv[1])) for name, d in self.detections.items()}

    def merge(self, other: "DetectionResult") -> None:
        """Add ``other``'s detections; a marker found there is no longer missing."""
        self.detections.update(other.detections)
        self.alternatives.update(other.alternatives)
        self.missing = [m for m in self.missing if m not in other.detections]
        self.missing.extend(m for m in other.missing if m not in self.missing and m not in self.detections)
        reasons = {**self.missing_reasons, **other.missing_reasons}
        self.missing_reasons = {m: reasons[m] for m in self.missing if m in reasons}

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"detections": {n: d.to_dict() for n, d in self.detections.items()},
                             "missing": list(self.missing)}
        if self.missing_reasons:
            d["missing_reasons"] = dict(self.missing_reasons)
        if self.alternatives:
            d["alternatives"] = {n: [a.to_dict() for a in alts] for n, alts in self.alternatives.items()}
        return d


def as_bgr(image: Any, where: str = "image") -> np.ndarray:
    """Validate an image and return it as uint8 BGR (H, W, 3)."""
    if not isinstance(image, np.ndarray):
        raise InputError(f"{where}: expected a NumPy image array, got {type(image).__name__}")
    if image.ndim == 2:
        image = np.repeat(image[:, :, None], 3, axis=2)
    if image.ndim != 3 or image.shape[2] not in (3, 4) or image.shape[0] < 2 or image.shape[1] < 2:
        raise InputError(f"{where}: expected an (H, W, 3) BGR image, got shape {image.shape}")
    if image.shape[2] == 4:
        image = image[:, :, :3]
    if image.dtype != np.uint8:
        if np.issubdtype(image.dtype, np.floating):
            if not np.all(np.isfinite(image)):
                raise InputError(f"{where}: image contains NaN or inf")
            scale = 255.0 if image.max() <= 1.0 else 1.0
            image = np.clip(image * scale + 0.5, 0, 255).astype(np.uint8)
        elif image.dtype == np.uint16:
            image = (image >> 8).astype(np.uint8)
        else:
            raise InputError(f"{where}: unsupported image dtype {image.dtype}")
    return np.ascontiguousarray(image)


def observations_of(detections: Mapping[str, DetectionResult], time: float | None = None, *,
                    include_predicted: bool = False) -> ObservationSet:
    """One :class:`ObservationSet` from each observer's detections (measured
    positions only, unless ``include_predicted``)."""
    return ObservationSet.concatenate([d.observations(r, time, include_predicted=include_predicted)
                                       for r, d in detections.items()])

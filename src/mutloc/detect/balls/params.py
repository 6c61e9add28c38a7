"""Tuning of the ball detector: one frozen dataclass with documented defaults."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from numbers import Real

import numpy as np

from ...errors import InputError

__all__ = ["DEFAULT_BALL_RADIUS_M", "BallParams", "value_lut"]

# Marker.extra["radius"] when a rig does not say (metres).
DEFAULT_BALL_RADIUS_M = 0.03


def _positive(what: str, val: object) -> None:
    if isinstance(val, bool) or not (isinstance(val, Real) and math.isfinite(val) and val > 0):
        raise InputError(f"{what} must be a positive number, got {val!r}")


def _positive_int(what: str, val: object) -> None:
    if isinstance(val, bool) or not (isinstance(val, (int, np.integer)) and val >= 1):
        raise InputError(f"{what} must be a positive integer, got {val!r}")


@dataclass(frozen=True)
class BallParams:
    """Every tuning value of :func:`~mutloc.detect.balls.detect_balls`.

    Invalid values raise :class:`~mutloc.errors.InputError` on construction.
    """

    #: Smallest image radius of a ball (pixels).
    min_radius_px: float = 2.0
    #: Largest image radius of a ball (pixels); ``None``: a third of the
    #: shorter image side.
    max_radius_px: float | None = None
    #: Half-width of the hue window around the nominal hue (degrees, below
    #: 90).  Light of a strong colour (or a bad white balance) turns hues:
    #: raise it then.
    hue_tol_deg: float = 12.0
    #: Factor of the coarse search image; ``None`` picks the largest of 1, 2,
    #: 4 that keeps ``min_radius_px`` at least 1.5 coarse pixels, and when
    #: that is 1 (the default ``min_radius_px=2``) searches at half
    #: resolution and falls back to full resolution (small blobs only) for
    #: markers left without a candidate.
    downscale: int | None = None
    #: Pixel values are sRGB-encoded (cameras, PNG, JPEG); ``False`` for
    #: linear images.
    srgb: bool = True
    #: Blobs per marker refined at full resolution (the best coarse ones).
    max_candidates: int = 3
    #: Detections scoring below this are reported missing.
    min_score: float = 0.25
    #: With a camera: distances (from the ball's apparent size, metres)
    #: outside this range make a blob implausible.
    distance_range_m: tuple[float, float] = (0.05, 200.0)

    #: A nominal colour with less saturation than this (0..1) has no usable
    #: hue: white, grey and black balls need a brightness test, which
    #: textured scenes defeat, so they are refused with a clear error.
    min_nominal_saturation: float = 0.25
    #: Likewise for a nominal colour darker than this value (0..1).
    min_nominal_value: float = 0.2
    #: Exponent of the values in which rim profiles of sRGB images are
    #: unmixed: encoded values raised to 1.7, part way to linear light.
    #: Optics and pixel area mix *light* (a profile is a linear mixture only
    #: in linear values), but JPEG and video codecs blur the chroma of the
    #: *encoded* values (4:2:0), and a fully linear unmixing turns that into
    #: an edge bias of ~0.2 px that follows the lighting.  Measured on exact
    #: renders (tests/test_detect_balls.py), 1.7 keeps the median error at
    #: ~0.02 px clean, ~0.07 px blurred, ~0.1 px after JPEG and after blur +
    #: noise + JPEG together, where linear light (~2.4) gives 0.01 / 0.03 /
    #: 0.21 / 0.15 px and encoded values (1.0) 0.06 / 0.10 / 0.05 / 0.16 px.
    mix_gamma: float = 1.7
    #: Sampling step along the rim rays (pixels).  Half a pixel keeps the
    #: trapezoid integral of a pixel-area-blurred step accurate to a few
    #: hundredths.
    step_px: float = 0.5
    #: Half-width (pixels) of the second, local window around each ray's
    #: edge: room for the blur of optics, pixels and JPEG, little for the
    #: background to change within.
    local_half_window_px: float = 2.5
    #: The local window (half-width, pixels) of the second round of rays of a
    #: ball whose rim the first round found nearly whole (at least
    #: ``whole_rim_share`` of its rays near the circle and kept by the fit):
    #: the ball and background colours are then taken nearer the edge, where
    #: they are the colours that mix in its pixels (a lit sphere's shading
    #: changes fast at its limb).  First-look centres of whole balls 0.082 ->
    #: 0.075 px on the Blender set and 0.041 -> 0.030 px on mutloc's renderer
    #: (docs/benchmarks.md).  A partly hidden ball keeps the wider window: its
    #: rays near the occluder need it (its poses got worse on both renderers
    #: with every ray narrowed).  At least ``4 * step_px``: the shading trend
    #: of the unmixing needs eight samples (1.75 px cost mutloc's renderer
    #: 0.03 -> 0.07 px).
    whole_rim_half_window_px: float = 2.0
    #: Share of a ball's rays that must be near its circle and kept by the fit
    #: for :attr:`whole_rim_half_window_px` (0.9: only half the gain; 0.6:
    #: the same centres as 0.8 but more partly hidden poses change).
    whole_rim_share: float = 0.8
    #: Without a camera, fitted ellipses more elongated than this are
    #: refused (a sphere's image reaches 1.4 only 45 deg off-axis).
    max_axis_ratio: float = 1.6
    #: The rig check tries at most this many candidates per marker ...
    max_joint_options: int = 4
    #: ... and gives up (keeping each marker's best) beyond this many
    #: combinations.
    max_joint_combos: int = 5000
    #: When the rig check's choice holds, but a pair of its balls is off
    #: the robot's distance by more than this (in allowed errors; 3 fails the
    #: check), the blobs passed over as smaller than an early good fit are
    #: refined too and the choice made again: a poster's disc of a ball's
    #: colour can outscore the ball and still pass at a distance.
    recheck_pair_error: float = 0.5
    #: A chosen ball whose rim was cut (an occluder) and whose radius is off
    #: its whole mate's by more than this share has its circle found again
    #: from the visible outline (:mod:`.occlusion`), in competition with its
    #: first fit: that fit may have taken the occluder's edge for rim.
    cut_size_tolerance: float = 0.08
    #: Once a blob of a marker scores this well, only bigger blobs of that
    #: marker are still refined.
    good_enough: float = 0.85
    #: Largest ball radius (full-resolution pixels) the full-resolution
    #: fallback of the hybrid search looks for: the half-resolution search
    #: finds balls of 1.5 coarse pixels and more, so this leaves a wide margin.
    fallback_max_radius_px: float = 8.0
    #: Another blob of a detected marker scoring at least this fraction of
    #: the chosen one is handed over as an alternative (the localizer picks
    #: the one the mutual geometry supports); 1 hands over none.
    alternative_ratio: float = 0.8
    #: Alternatives handed over per marker at most.
    max_alternatives: int = 2

    #: A ball with less of its rim visible (inlier rays of the fit over all
    #: rays) is reported missing, with the reason, rather than measured
    #: from too short an arc (its centre would be biased by the occluder).
    min_visible_fraction: float = 0.25
    #: When fewer of the first round's rim points than this share lie near
    #: the coarse circle (an occluder split the blob or cut into it), the
    #: circle is searched again at full resolution from the visible
    #: outline (:mod:`.occlusion`).
    recentre_below: float = 0.85
    #: Rim points where the measured outline turns more than this against
    #: the ray (degrees: the edge's normal is not radial) lie on an
    #: occluder's edge, not on the ball's rim, and are left out of the fit.
    max_rim_slope_deg: float = 35.0
    #: Colour of the light: ``"auto"`` estimates it (grey world) and
    #: corrects colours before the hue test when the image's cast is strong
    #: (see ``auto_white_balance_below``); ``"off"`` never corrects; an
    #: sRGB ``(r, g, b)`` gives the light's colour (e.g. ``(255, 176, 96)``
    #: for tungsten).
    white_balance: str | tuple[int, int, int] = "auto"
    #: ``"auto"`` corrects only when the image's mean linear colour has its
    #: weakest channel below this share of its strongest: white-lit indoor
    #: scenes measure 0.74-0.85 (coloured posters), tungsten light ~0.1.
    auto_white_balance_below: float = 0.6

    def __post_init__(self) -> None:
        _positive("min_radius_px", self.min_radius_px)
        _positive("hue_tol_deg", self.hue_tol_deg)
        if self.hue_tol_deg >= 90:
            raise InputError(f"hue_tol_deg must be below 90, got {self.hue_tol_deg!r}")
        try:
            dmin, dmax = (float(x) for x in self.distance_range_m)
        except (TypeError, ValueError):
            raise InputError(
                f"distance_range_m must be (min, max) in metres, got {self.distance_range_m!r}"
            ) from None
        if not (0 <= dmin < dmax):
            raise InputError(
                f"distance_range_m must be (min, max) with 0 <= min < max, got {self.distance_range_m!r}"
            )
        object.__setattr__(self, "distance_range_m", (dmin, dmax))
        m = self.max_radius_px
        if m is not None and (
            isinstance(m, bool) or not (isinstance(m, Real) and math.isfinite(m) and m > self.min_radius_px)
        ):
            raise InputError(f"max_radius_px must be a number above min_radius_px, got {m!r}")
        _positive_int("max_candidates", self.max_candidates)
        if self.downscale is not None:
            _positive_int("downscale", self.downscale)
        for what in ("mix_gamma", "step_px", "local_half_window_px", "whole_rim_half_window_px", "max_axis_ratio",
                     "fallback_max_radius_px", "recheck_pair_error", "cut_size_tolerance"):
            _positive(what, getattr(self, what))
        _positive_int("max_joint_options", self.max_joint_options)
        _positive_int("max_joint_combos", self.max_joint_combos)
        _positive_int("max_alternatives", self.max_alternatives)
        if not 0 < self.max_rim_slope_deg < 90:
            raise InputError(f"max_rim_slope_deg must be in (0, 90), got {self.max_rim_slope_deg!r}")
        wb = self.white_balance
        if isinstance(wb, str):
            if wb not in ("auto", "off"):
                raise InputError(f"white_balance must be 'auto', 'off' or an (r, g, b) colour, got {wb!r}")
        else:
            try:
                rgb = tuple(float(c) for c in wb)
            except (TypeError, ValueError):
                raise InputError(f"white_balance must be 'auto', 'off' or an (r, g, b) colour, got {wb!r}") from None
            if len(rgb) != 3 or not all(0 < c <= 255 for c in rgb):
                raise InputError(f"white_balance colour must be 3 values in (0, 255], got {wb!r}")
            object.__setattr__(self, "white_balance", rgb)
        for what in ("min_score", "good_enough", "alternative_ratio", "min_nominal_saturation", "min_nominal_value",
                     "min_visible_fraction", "recentre_below", "auto_white_balance_below", "whole_rim_share"):
            val = getattr(self, what)
            if isinstance(val, bool) or not (isinstance(val, Real) and 0 <= val <= 1):
                raise InputError(f"{what} must be a number in [0, 1], got {val!r}")


@functools.lru_cache(maxsize=8)
def value_lut(srgb: bool, mix_gamma: float) -> np.ndarray:
    """uint8 pixel value -> the value rims are unmixed in (``(v / 255) ** mix_gamma``; linear images: ``v / 255``)."""
    x = np.arange(256) / 255.0
    return (x**mix_gamma if srgb else x).astype(np.float32)

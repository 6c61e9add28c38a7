"""Banded ("barcode") cylinder markers: band geometry and a detector
(see :mod:`mutloc.detect.cylinders.detector` for how it works)."""

from .detector import detect_cylinders
from .geometry import BAND_SEPARATOR, band_marker_names, band_points, cylinder_spec, expand_cylinder_bands

__all__ = ["BAND_SEPARATOR", "band_marker_names", "band_points", "cylinder_spec", "detect_cylinders",
           "expand_cylinder_bands"]

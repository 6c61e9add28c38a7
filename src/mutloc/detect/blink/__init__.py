"""Blinking-light markers: found and identified by their blink (see
:mod:`mutloc.detect.blink.tracker` for how), in stages: motion, measure,
association, identity."""

from .motion import GlobalMotion
from .params import BlinkParams
from .tracker import BlinkTracker

__all__ = ["BlinkParams", "BlinkTracker", "GlobalMotion"]

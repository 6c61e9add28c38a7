"""Blinking-light markers: found and identified by their blink (see
:mod:`mutloc.detect.blink.tracker` for how), in stages: motion, measure,
association, identity; one channel per colour of light
(:mod:`mutloc.detect.blink.channels`)."""

from .channels import BlinkTracker
from .motion import GlobalMotion
from .params import BlinkParams

__all__ = ["BlinkParams", "BlinkTracker", "GlobalMotion"]

"""Argument types and helpers shared by the subcommand modules."""

from __future__ import annotations

import argparse
import math

__all__ = ["positive_float", "nonnegative_float", "output_path", "robot_value", "int_in_range"]


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0."""
    try:
        x = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not (math.isfinite(x) and x > 0):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text!r}")
    return x


def nonnegative_float(text: str) -> float:
    """argparse type: a finite number >= 0."""
    try:
        x = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not (math.isfinite(x) and x >= 0):
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0, got {text!r}")
    return x


def output_path(text: str | None) -> str | None:
    """``None`` for stdout (no option or ``-``), else the path."""
    return None if text in (None, "-") else text


def robot_value(text: str) -> tuple[str, str]:
    """argparse type: ``ROBOT=VALUE`` (an image path, a stream, a topic)."""
    robot, sep, value = text.partition("=")
    if not sep or not robot or not value:
        raise argparse.ArgumentTypeError(f"expected ROBOT=VALUE, got {text!r}")
    return robot, value


def int_in_range(lo: int, hi: int | None = None, what: str = "value"):
    """argparse type: an integer in ``lo..hi`` (no upper bound if ``hi`` is None)."""

    def parse(text: str) -> int:
        try:
            n = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
        if n < lo or (hi is not None and n > hi):
            bound = f"in {lo}..{hi}" if hi is not None else f">= {lo}"
            raise argparse.ArgumentTypeError(f"{what} must be {bound}, got {text!r}")
        return n

    return parse

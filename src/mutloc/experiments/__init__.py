"""Reproductions of the paper's experiments (``mutloc experiment NAME``)."""

from __future__ import annotations

__all__ = ["run_noise"]


def run_noise(*args, **kwargs):
    """See :func:`mutloc.experiments.noise.run_noise`."""
    from .noise import run_noise as _run

    return _run(*args, **kwargs)

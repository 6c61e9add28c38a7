"""Reproductions of the paper's experiments (``mutloc experiment NAME``).

Each ``run_NAME(out_dir, seed=..., progress=..., command=...)`` writes
``out_dir/NAME/results.json`` (SPEC), ``report.md`` and plots, and returns the
results; :func:`run_all` runs them all and writes ``out_dir/report.md``.
"""

from __future__ import annotations

__all__ = ["run_noise", "run_localization", "run_reconstruction", "run_calibration", "run_all", "EXPERIMENTS"]

EXPERIMENTS = ("noise", "localization", "reconstruction")


def run_noise(*args, **kwargs):
    """See :func:`mutloc.experiments.noise.run_noise`."""
    from .noise import run_noise as _run

    return _run(*args, **kwargs)


def run_localization(*args, **kwargs):
    """See :func:`mutloc.experiments.localization.run_localization`."""
    from .localization import run_localization as _run

    return _run(*args, **kwargs)


def run_reconstruction(*args, **kwargs):
    """See :func:`mutloc.experiments.reconstruction.run_reconstruction`."""
    from .reconstruction import run_reconstruction as _run

    return _run(*args, **kwargs)


def run_calibration(*args, **kwargs):
    """See :func:`mutloc.experiments.calibration.run_calibration` (not part of ``all``: not the paper's)."""
    from .calibration import run_calibration as _run

    return _run(*args, **kwargs)


def run_all(*args, **kwargs):
    """See :func:`mutloc.experiments.report.run_all`."""
    from .report import run_all as _run

    return _run(*args, **kwargs)

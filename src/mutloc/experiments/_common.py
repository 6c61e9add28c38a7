"""What every experiment shares: versions, medians, number formatting, output."""

from __future__ import annotations

import json
import math
import platform
from pathlib import Path
from typing import Any, Iterable

import numpy as np

__all__ = ["versions", "median", "fmt", "pose_errors", "write_results", "reproduce_lines", "pyplot", "save_figure"]


def versions() -> dict[str, str]:
    """Versions of Python and the packages the results depend on."""
    from importlib.metadata import PackageNotFoundError, version

    out = {"python": platform.python_version()}
    for pkg in ("mutloc", "numpy", "scipy", "numba", "opencv-python-headless", "matplotlib", "pycolmap"):
        try:
            out[pkg] = version(pkg)
        except PackageNotFoundError:
            out[pkg] = "unknown"
    return out


def median(values: Iterable[float]) -> float:
    """Median, NaN for no values."""
    v = list(values)
    return float(np.median(v)) if v else float("nan")


def pose_errors(est: Any, truth: Any) -> tuple[float, float]:
    """(translation error m, rotation error deg, the paper's angle) of an
    estimate against the truth; both need ``.R`` and ``.t``."""
    from ..core.geometry import rotation_error_deg, translation_error

    return translation_error(est.t, truth.t), float(rotation_error_deg(est.R, truth.R))


def fmt(x: float, scale: float = 1.0, digits: int = 2) -> str:
    """``x * scale`` with ``digits`` decimals, or n/a."""
    return "n/a" if x is None or not math.isfinite(x) else f"{x * scale:.{digits}f}"


def _finite(x: Any) -> Any:
    """NaN/inf (a method that never succeeded) as JSON null, recursively."""
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if isinstance(x, dict):
        return {k: _finite(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_finite(v) for v in x]
    return x


def write_results(results: dict[str, Any], out: Path) -> None:
    """``out/results.json`` (SPEC "Experiment results"); undefined numbers are null."""
    with open(out / "results.json", "w", encoding="utf-8") as f:
        json.dump(_finite(results), f, indent=2, allow_nan=False)
        f.write("\n")


def reproduce_lines(results: dict[str, Any]) -> list[str]:
    """The report's closing "Reproduce" section."""
    return ["## Reproduce", "", "```", results["command"], "```", "",
            f"Seed {results['seed']}; run time {results['elapsed_s']:.1f} s.", "",
            "Versions: " + ", ".join(f"{k} {v}" for k, v in results["versions"].items()) + ".", ""]


def pyplot():
    """Matplotlib's pyplot on the non-interactive Agg backend."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig: Any, path: Path, dpi: int = 120) -> None:
    """Lay out, write and close a Matplotlib figure."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)

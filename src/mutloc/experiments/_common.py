"""What every experiment shares: versions, medians, number formatting, output."""

from __future__ import annotations

import json
import math
import platform
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterable, Iterator

import numpy as np

from .._extras import require

__all__ = ["versions", "median", "fmt", "pose_errors", "write_results", "reproduce_lines", "pyplot", "save_figure",
           "cpu_seconds", "StageTimer", "timing_lines"]


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


def cpu_seconds() -> float:
    """CPU time (user + system) of this process -- every thread, COLMAP's and
    Numba's included -- and of its finished children, in seconds."""
    try:
        import resource
    except ImportError:  # not on Unix: this process only
        return time.process_time()
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


class StageTimer:
    """Wall-clock and CPU seconds per named stage of an experiment.

    ``with timer("render frames"): ...`` adds to that stage (stages may be
    entered many times; they should not nest).  On a machine shared with
    other jobs the CPU time measures the work and the wall time the wait as
    well, so both are kept.
    """

    def __init__(self) -> None:
        self.stages: dict[str, dict[str, float]] = {}
        self._wall0, self._cpu0 = time.perf_counter(), cpu_seconds()

    @contextmanager
    def __call__(self, name: str) -> Iterator[None]:
        w, c = time.perf_counter(), cpu_seconds()
        try:
            yield
        finally:
            s = self.stages.setdefault(name, {"wall_s": 0.0, "cpu_s": 0.0})
            s["wall_s"] += time.perf_counter() - w
            s["cpu_s"] += cpu_seconds() - c

    def as_dict(self) -> dict[str, Any]:
        """``{"wall_s", "cpu_s"}`` since the timer was made, and per stage
        (plus ``other``: the time outside every stage)."""
        wall, cpu = time.perf_counter() - self._wall0, cpu_seconds() - self._cpu0
        stages = {n: {k: round(v, 2) for k, v in s.items()} for n, s in self.stages.items()}
        stages["other"] = {"wall_s": round(wall - sum(s["wall_s"] for s in self.stages.values()), 2),
                           "cpu_s": round(cpu - sum(s["cpu_s"] for s in self.stages.values()), 2)}
        return {"wall_s": round(wall, 2), "cpu_s": round(cpu, 2), "stages": stages}


def timing_lines(timing: dict[str, Any], title: str = "Run time by stage") -> list[str]:
    """A Markdown table of a :meth:`StageTimer.as_dict` result."""
    lines = [f"{title} (CPU = user + system time of every thread, wall = elapsed; on a shared machine the "
             "wall time includes waiting for the CPU):", "", "| stage | CPU s | wall s |", "|---|---|---|"]
    for name, s in timing["stages"].items():
        lines.append(f"| {name} | {s['cpu_s']:.1f} | {s['wall_s']:.1f} |")
    lines += [f"| **total** | **{timing['cpu_s']:.1f}** | **{timing['wall_s']:.1f}** |", ""]
    return lines


def reproduce_lines(results: dict[str, Any]) -> list[str]:
    """The report's closing "Reproduce" section (with the run time by stage when timed)."""
    lines = ["## Reproduce", "", "```", results["command"], "```", "",
             f"Seed {results['seed']}; run time {results['elapsed_s']:.1f} s.", ""]
    if "timing" in results:
        lines += timing_lines(results["timing"])
    return lines + ["Versions: " + ", ".join(f"{k} {v}" for k, v in results["versions"].items()) + ".", ""]


def pyplot():
    """Matplotlib's pyplot on the non-interactive Agg backend."""
    matplotlib = require("matplotlib", "the experiments' plots", "experiments")

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig: Any, path: Path, dpi: int = 120) -> None:
    """Lay out, write and close a Matplotlib figure."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)

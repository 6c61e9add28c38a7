"""Compile mutloc's Numba kernels once, before the test workers start.

On a fresh clone Numba's cache is cold: every kernel is compiled on first use,
and with ``pytest -n 2`` both workers compile the same kernels at the same time
(each its own copy, the second write to the cache wasted).  Compiling takes
minutes in all on the 2-core machine.  ``conftest.py`` runs this script on the
xdist controller, in two processes at once -- one per group of kernels -- so
each kernel is compiled once and the workers load it from the cache.

    python tests/warm_kernels.py balls     # the balls detector, render, localize, track (``mutloc demo``)
    python tests/warm_kernels.py others    # tags, cylinders, lights, teams

It drives the CLI in-process on tiny simulated scenes; what it computes is
thrown away.  A failure here only means the tests compile what they use
themselves (slower, not wrong): it prints one line and exits non-zero.
"""

from __future__ import annotations

import contextlib
import io
import sys
import tempfile
from pathlib import Path


def _cli(*argv: str) -> None:
    from mutloc.cli.main import main

    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        rc = main(list(argv))
    if rc != 0:
        last = (err.getvalue().strip().splitlines() or [""])[-1]
        raise RuntimeError(f"mutloc {argv[0]} exited {rc}: {last}")


def warm_balls(tmp: Path) -> None:
    """Render, detect balls, localize (one pinhole pair, back-to-back fisheyes), second look, track."""
    _cli("demo", "--out", str(tmp / "demo"), "--frames", "3", "--no-progress")


def _solve_without_images(tmp: Path) -> None:
    """Localize and track balls from simulated detections: the pose solver and the filter, no rendering."""
    from mutloc.io import save_rig
    from mutloc.io.logs import write_observation_log
    from mutloc.sim.tracking import observation_sequence
    from mutloc.sim.world import standard_rig

    d = tmp / "solve"
    d.mkdir()
    rig = standard_rig("balls")
    save_rig(rig, d / "rig.yaml")
    seq = observation_sequence(rig, duration=0.5, fps=10.0, seed=1)
    write_observation_log(d / "log.jsonl", seq.frames)
    _cli("track", "--rig", str(d / "rig.yaml"), "--observations", str(d / "log.jsonl"), "--out", str(d / "out"),
         "--no-progress")


def warm_others(tmp: Path) -> None:
    """Tags and cylinders in images, blinking lights in a short sequence, a team solved and tracked.

    It starts with the solver on simulated detections (no rendering) while the other group compiles the
    renderer, so that each compiles its own kernels and finds the other's in the cache when it gets there:
    both started by rendering, and both compiled the renderer's and the solver's kernels at the same time."""
    _solve_without_images(tmp)
    for kind in ("tags", "cylinders"):
        d = tmp / kind
        _cli("simulate", "--out", str(d), "--markers", kind, "--size", "480x270", "--focal", "400",
             "--no-progress")
        _cli("localize-images", "--rig", str(d / "rig.yaml"), "--image", f"p={d / 'p.png'}",
             "--image", f"q={d / 'q.png'}")
    d = tmp / "lights"
    _cli("simulate", "--out", str(d), "--markers", "lights", "--frames", "10", "--fps", "30", "--size", "480x270",
         "--focal", "400", "--no-progress")
    _cli("track", "--rig", str(d / "rig.yaml"), "--stream", f"p={d / 'p'}", "--stream", f"q={d / 'q'}",
         "--out", str(d / "out"), "--no-progress")
    d = tmp / "team"
    _cli("simulate", "--robots", "3", "--frames", "6", "--out", str(d), "--size", "480x270", "--focal", "400",
         "--no-progress")
    _cli("track", "--rig", str(d / "rig.yaml"), *(f"--stream=r{i}={d / f'r{i}'}" for i in range(3)),
         "--out", str(d / "out"), "--no-progress")


GROUPS = {"balls": warm_balls, "others": warm_others}


def main(argv: list[str]) -> int:
    if len(argv) != 1 or argv[0] not in GROUPS:
        print(f"usage: warm_kernels.py {{{','.join(GROUPS)}}}", file=sys.stderr)
        return 2
    try:
        with tempfile.TemporaryDirectory(prefix="mutloc-warm-") as tmp:
            GROUPS[argv[0]](Path(tmp))
    except Exception as exc:  # noqa: BLE001 -- a warm-up that fails only costs time; say so in one line
        print(f"warm_kernels {argv[0]}: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

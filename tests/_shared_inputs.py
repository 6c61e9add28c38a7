"""Expensive test inputs (rendered sequences) made once per test run and shared by its xdist workers.

``shared(tmp_path_factory, key, make)`` returns ``make()``: computed by the first worker that asks for
``key``, pickled, and read back by any other test or worker asking for the same key in the same run (a file
lock is held while it is made, so it is never made twice).  The key must name every parameter the value
depends on.  The folder is the run's own base temporary folder (``pytest-N``, shared by the workers of one
``pytest -n``): a run never reads another run's values, so a changed renderer is always rendered afresh.
"""

from __future__ import annotations

import fcntl
import os
import pickle
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any


def _folder(tmp_path_factory: Any) -> Path:
    base = Path(tmp_path_factory.getbasetemp())
    if os.environ.get("PYTEST_XDIST_WORKER"):
        base = base.parent  # a worker's base is pytest-N/popen-gwK; pytest-N is the run's
    folder = base / "shared-inputs"
    folder.mkdir(exist_ok=True)
    return folder


def shared(tmp_path_factory: Any, key: str, make: Callable[[], Any]) -> Any:
    """``make()``, made once per run for ``key`` (see the module's docstring)."""
    name = re.sub(r"[^A-Za-z0-9_.=-]", "_", key)
    folder = _folder(tmp_path_factory)
    path = folder / f"{name}.pickle"
    with open(folder / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if path.exists():
            with open(path, "rb") as f:
                return pickle.load(f)
        value = make()
        part = path.with_suffix(".part")
        with open(part, "wb") as f:
            pickle.dump(value, f, protocol=pickle.HIGHEST_PROTOCOL)
        os.replace(part, path)
        return value


def clock_offset_pair(tmp_path_factory: Any) -> Path:
    """The folder of ``write_simulation(frames=60, fps=30, seed=0, size=(480, 270), focal=400, clock_offset={"p":
    0.04})``: two seconds of the balls pair, p stamping its frames 40 ms behind q (``p/frames.csv``; q's
    ``q/frames.csv`` holds the true times), made once per run for tests/test_track_stream_clocks.py and
    tests/test_live_end_to_end.py (its images are those of the same scene without the offset: a clock offset
    changes only the stamps).  Read it, never write into it: copy it first."""

    def make() -> Path:
        from mutloc.sim.scenario import write_simulation

        out = _folder(tmp_path_factory) / "clock-offset-pair"
        write_simulation(out, frames=60, fps=30.0, seed=0, size=(480, 270), focal=400.0, clock_offset={"p": 0.04})
        return out

    return shared(tmp_path_factory, "clock-offset-pair-balls-60f-30fps-seed0-480x270-f400-p40ms", make)

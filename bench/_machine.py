"""What machine a benchmark ran on (recorded beside its figures)."""

from __future__ import annotations

import os
import platform
from pathlib import Path

import cv2
import numba
import numpy as np

import mutloc


def machine() -> dict:
    """CPU model, cores, load average and library versions."""
    cpu = "unknown"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        load = list(os.getloadavg())
    except OSError:
        load = None
    return {
        "cpu": cpu,
        "cores": os.cpu_count(),
        "load_average_at_start": load,
        "python": platform.python_version(),
        "numpy": np.__version__,
        "numba": numba.__version__,
        "opencv": cv2.__version__,
        "mutloc": mutloc.__version__,
    }


#: Where the benchmarks write their figures (one JSON per benchmark).
RESULTS = Path(__file__).resolve().parent / "results"


def result_file(name: str) -> str:
    """``bench/results/<name>``: the default ``--out`` of a benchmark."""
    return str(RESULTS / name)


def dds_domain():
    """A DDS domain id no other running process holds, held until the returned lease is released (a
    ``with`` block): the tests' allocator (tests/dds_domains.py, the one place domain ids are handed out),
    so a benchmark never meets a test run or another benchmark on a domain, nor a port of the ephemeral
    range.  ``lease.domain`` is the id."""
    import sys

    tests = str(Path(__file__).resolve().parent.parent / "tests")
    if tests not in sys.path:
        sys.path.insert(0, tests)
    from dds_domains import allocate

    return allocate()


class cpu_hog:
    """``with cpu_hog(on):`` another process keeping one core busy for the block (``on`` False: nothing),
    started in its own process group and killed by it in a ``finally`` (the issue's "beside a CPU hog")."""

    def __init__(self, on: bool = True) -> None:
        self.on, self.proc = on, None

    def __enter__(self) -> "cpu_hog":
        import subprocess
        import sys

        if self.on:
            self.proc = subprocess.Popen([sys.executable, "-c", "while True: pass"], start_new_session=True)
        return self

    def __exit__(self, *exc) -> None:
        import signal

        if self.proc is not None:
            try:
                os.killpg(self.proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            self.proc.wait()


def load_now() -> list:
    """The 1-, 5- and 15-minute load averages (``uptime``'s), rounded."""
    return [round(x, 2) for x in os.getloadavg()]

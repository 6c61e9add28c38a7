"""Cold start: a first run's Numba compile, on an empty kernel cache.

    python bench/bench_cold_start.py [--warm-up] SRC [SRC ...]

For each source tree ``SRC`` (this clone's root, or e.g. ``git archive`` of an
older commit unpacked somewhere), at the same time so that each sees the same
machine load: ``mutloc demo --frames 3`` on an empty cache
(``MUTLOC_CACHE_DIR``), or with ``--warm-up`` the test suite's warm-up
(``tests/warm_kernels.py``, both groups at once, as ``tests/conftest.py``
runs them).  Prints each one's wall and CPU seconds and the load (``uptime``);
CPU seconds are the figure to compare on a shared machine.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def _start(src: Path, cache: str, argv: list[str], out: str) -> subprocess.Popen:
    env = dict(os.environ, MUTLOC_CACHE_DIR=cache, PYTHONPATH=str(src / "src"))
    return subprocess.Popen([sys.executable, *argv], cwd=src, env=env, stdout=open(out, "w"),
                            stderr=subprocess.STDOUT)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("src", nargs="+", type=Path)
    ap.add_argument("--warm-up", action="store_true", help="the test suite's warm-up instead of the demo")
    a = ap.parse_args()
    print(subprocess.run(["uptime"], check=False, capture_output=True, text=True).stdout.strip())
    with tempfile.TemporaryDirectory(prefix="mutloc-cold-") as tmp:
        runs = []
        for i, src in enumerate(a.src):
            src = src.resolve()
            cache = os.path.join(tmp, f"cache{i}")
            if a.warm_up:
                procs = [_start(src, cache, ["tests/warm_kernels.py", g], os.path.join(tmp, f"log{i}{g}"))
                         for g in ("balls", "others")]
            else:
                procs = [_start(src, cache, ["-m", "mutloc", "demo", "--frames", "3", "--no-progress", "--out",
                                             os.path.join(tmp, f"demo{i}")], os.path.join(tmp, f"log{i}"))]
            runs.append((src, procs, time.perf_counter()))
        done = {}  # pid -> (end time, CPU seconds, exit code); os.wait4 gives each child's own CPU time
        while len(done) < sum(len(procs) for _, procs, _ in runs):
            pid, status, ru = os.wait4(-1, 0)
            done[pid] = (time.perf_counter(), ru.ru_utime + ru.ru_stime, os.waitstatus_to_exitcode(status))
        for src, procs, t0 in runs:
            ends = [done[p.pid] for p in procs]
            print(f"{src}: {max(e[0] for e in ends) - t0:.0f} s wall, {sum(e[1] for e in ends):.0f} s CPU, "
                  f"exit {[e[2] for e in ends]}")
    print(subprocess.run(["uptime"], check=False, capture_output=True, text=True).stdout.strip())
    return 0


if __name__ == "__main__":
    sys.exit(main())

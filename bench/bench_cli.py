#!/usr/bin/env python
"""Start-up time of the command line: ``mutloc --help`` and
``mutloc localize --help`` (wall clock of a fresh process, median of runs),
next to ``python -c pass`` measured in the same run.

    python bench/bench_cli.py [--runs 15]

Writes bench/results/cli_results.json.  Help must not load Numba, SciPy or OpenCV
(tests/test_cli_trust.py checks which modules load; this measures the time).
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _machine import machine, result_file  # noqa: E402


def wall(cmd: list[str], runs: int) -> float:
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=True)
        times.append(time.perf_counter() - t0)
    times.sort()
    return times[len(times) // 2]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=15)
    ap.add_argument("--out", default=result_file("cli_results.json"))
    args = ap.parse_args(argv)
    exe = shutil.which("mutloc") or str(Path(sys.executable).with_name("mutloc"))
    cmds = {"python -c pass": [sys.executable, "-c", "pass"],
            "mutloc --help": [exe, "--help"],
            "mutloc localize --help": [exe, "localize", "--help"],
            "mutloc track --help": [exe, "track", "--help"]}
    for c in cmds.values():  # warm the file cache
        subprocess.run(c, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=True)
    res = {"machine": machine(), "runs": args.runs,
           "seconds": {name: wall(c, args.runs) for name, c in cmds.items()}}
    for name, s in res["seconds"].items():
        print(f"{name:24} {1000 * s:7.1f} ms")
    Path(args.out).write_text(json.dumps(res, indent=2))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

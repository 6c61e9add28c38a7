#!/usr/bin/env python
"""Kill test of the streaming writers under load: a child writes rows to
every streaming writer as fast as it can (no pause between rows) and is
killed with SIGKILL after a random 0.2-1.5 s; every file must then parse
and hold a prefix of the rows written, at least as many as the child
reported (the checks of tests/test_streaming_outputs.py).

    python bench/kill_streaming.py --trials 60

Prints one line per failed trial and a summary; writes
bench/results/kill_streaming_results.json.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))
import test_streaming_outputs as T  # noqa: E402

ROWS = 3000


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=60)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    child = T.CHILD.replace("time.sleep(0.01)", "pass").replace("range(N_ROWS)", f"range({ROWS})")
    T.N_ROWS = ROWS
    rng = random.Random(args.seed)
    res: dict = {"trials": 0, "ok": 0, "errors": [], "rows_reported": []}
    for trial in range(args.trials):
        out = Path(tempfile.mkdtemp(prefix="mutloc-kill-"))
        proc = subprocess.Popen([sys.executable, "-c", child, str(out)], stdout=subprocess.PIPE,
                                stderr=subprocess.DEVNULL, text=True, start_new_session=True)
        try:
            if proc.stdout.readline() != "ready\n":
                raise SystemExit("the child did not start")
            time.sleep(rng.uniform(0.2, 1.5))
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
            reported = max([int(x) for x in proc.stdout.read().split() if x.isdigit()] + [-1]) + 1
        finally:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
            proc.stdout.close()
        res["trials"] += 1
        res["rows_reported"].append(reported)
        try:
            T._check_files(out, reported, clean=False)
            res["ok"] += 1
        except Exception as exc:  # noqa: BLE001 - every failure is reported
            res["errors"].append(f"trial {trial}: {type(exc).__name__}: {str(exc)[:300]}")
            print(res["errors"][-1], flush=True)
        shutil.rmtree(out)
    print(f"{res['ok']} of {res['trials']} killed runs left every file readable "
          f"(rows written before the kill: {min(res['rows_reported'])}-{max(res['rows_reported'])})")
    (HERE / "results" / "kill_streaming_results.json").write_text(json.dumps(res, indent=1) + "\n")


if __name__ == "__main__":
    main()

#!/usr/bin/env python
"""A node killed and restarted 20 times during a run, for real (issue 38):
``mutloc node`` and ``mutloc localizer`` processes on DDS over loopback.

bench/node_outages.py feeds the localizer class, in one process, the messages
the nodes would send; here every part is the program a user runs:

* a ``mutloc localizer`` process (``--out``: its trajectory file gives each
  row's status),
* one ``mutloc node --realtime --loop`` process per robot, replaying its
  rendered camera (``mutloc simulate``'s balls rig and scene, 480x270, 30
  fps, as BMP: a replayed frame costs a copy, as a camera driver's does),
  both released in step (``--start-at``),
* this process, a subscriber like any other: every pose published on
  ``/mutloc/p_in_q``, every ``/diagnostics`` message, q's observation
  messages (to see when its node is back), with their arrival times.

The sequence is one period of the default figure (16 s: p's sway, in-out
and wobble and q's pan all repeat), looped: the replay goes on without a
jump, and the truth at any capture time is that of its phase in the period.

Twenty times q's node is killed (SIGKILL to its process group), left down
0.5-4 s (uniform, seeded) and started again -- the same command, replaying q's
camera from the frame due at the time it is expected to be ready (a camera
that was running while its node was down; its frames released in step with
p's); a node that starts later than expected releases its first frames late,
stamped when they were due (what a restarted node does to the localizer
either way: old stamps, dropped as late).  The node is killed again 1-2 s
after the localizer published a pose again, so every restart must be picked
up.  ``down`` below is kill -> the new process launched; ``gap`` is q's last
capture before the kill -> its first capture received after the restart (the
outage the localizer sees: down + the node's start-up).

Counted, per run: every pose received; poses beyond 5 sigma of their own
covariance against the rendered truth (NEES above 39.5, chi2_6's two-sided
5-sigma quantile), by the row's status (the localizer's trajectory file);
poses per frame instant with q up and with q down; each restart picked up
or not (a pose after q's first new capture); what ``/diagnostics`` said for
q (and p) while q was down, by how long q had been silent (< warn_after 0.5
s, 0.5-1 s, > max_coast 1 s), and the messages beyond max_coast that did
not say q is stale (none should); the localizer's own summary line.
With the rig right, and with every marker of the rig file 1-2 cm off
(``mutloc.sim.calibration.perturb_rig``, as bench/node_outages.py; the
images are those of the true markers).  Idle and beside a CPU hog (one
busy process, ``_machine.cpu_hog``); the load average before and after.

    python bench/node_restarts.py [--runs 1] [--restarts 20] [--load idle hog] [--rig right wrong]
                                  [--work DIR]

Writes bench/results/node_restarts.json.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _machine import cpu_hog, dds_domain, load_now, machine, result_file  # noqa: E402
from bench_live import raw_copy  # noqa: E402

from mutloc.core.geometry import matrix_from_quaternion_xyzw, so3_log  # noqa: E402
from mutloc.io import load_rig, save_rig  # noqa: E402
from mutloc.io.ros import spec_covariance  # noqa: E402
from mutloc.live import messages as M  # noqa: E402
from mutloc.live.dds import Bus  # noqa: E402
from mutloc.signals import stop_process_group  # noqa: E402
from mutloc.sim.calibration import perturb_rig  # noqa: E402
from mutloc.sim.scenario import write_simulation  # noqa: E402
from mutloc.signals import kill_process_group  # noqa: E402

FPS = 30.0
PERIOD = 16.0  # the default figure repeats every 16 s (8 s sway and pan, 4 s in-out, 16/3 s wobble)
FRAMES = int(round(PERIOD * FPS))
SIZE, FOCAL = (480, 270), 400.0
FIVE_SIGMA_NEES = 39.5  # chi2_6 at the two-sided 5-sigma tail (5.7e-7)
WARN_AFTER, MAX_COAST = 0.5, 1.0  # the localizer's defaults (mutloc.live.localizer)
LEVELS = {M.OK: "OK", M.WARN: "WARN", M.ERROR: "ERROR", M.STALE: "STALE"}
EXE = [sys.executable, "-m", "mutloc.cli.main"]


def render(work: Path) -> Path:
    """One period of the moving pair, rendered once (kept in ``work``), each robot's images as BMP."""
    sim = work / f"sim{FRAMES}"
    if not (sim / "truth.tum").exists():
        print(f"rendering {FRAMES} frames per robot into {sim} (once)", flush=True)
        write_simulation(sim, frames=FRAMES, fps=FPS, size=SIZE, focal=FOCAL)
    bmp = work / f"sim{FRAMES}_bmp"
    for r in ("p", "q"):
        if len(list((bmp / r).glob("*.bmp"))) != FRAMES:
            raw_copy(sim / r, bmp / r)
        (bmp / r / "frames.csv").write_text((sim / "frames.csv").read_text())
    for name in ("rig.yaml", "truth.tum"):
        (bmp / name).write_bytes((sim / name).read_bytes())
    return bmp


def truth_of(folder: Path) -> list:
    """T_qp at each frame of the period (truth.tum), as (R, t)."""
    rows = [[float(x) for x in ln.split()] for ln in (folder / "truth.tum").read_text().splitlines()
            if ln.strip() and not ln.startswith("#")]
    assert len(rows) == FRAMES
    return [(matrix_from_quaternion_xyzw(np.array(r[4:8])), np.array(r[1:4])) for r in rows]


def rotated(folder: Path, first: int, dest: Path) -> Path:
    """``folder``'s frames from ``first`` on, then its first ones (symbolic links), stamped on: a loop of the
    same period starting at frame ``first`` (its first stamp ``first / FPS``)."""
    dest.mkdir(parents=True)
    lines = ["frame,timestamp"]
    for i in range(FRAMES):
        k = (first + i) % FRAMES
        (dest / f"{i:06d}.bmp").symlink_to(folder / f"{k:06d}.bmp")
        lines.append(f"{i},{(first + i) / FPS:.9f}")
    (dest / "frames.csv").write_text("\n".join(lines) + "\n")
    return dest


class Listener:
    """This process's subscriber: poses of p in q, /diagnostics and q's observations, with arrival times."""

    def __init__(self, domain: int) -> None:
        T = M.ros_types()
        self.bus = Bus(domain, loopback=True)
        self.readers = {"pose": self.bus.reader(M.pose_topic("p", "q"), T.PoseWithCovarianceStamped, depth=100),
                        "diag": self.bus.reader(M.DIAGNOSTICS_TOPIC, T.DiagnosticArray, depth=50),
                        "q": self.bus.reader(M.observations_topic("q"), T.Observations, depth=100)}
        self.poses: list[tuple[float, float, object]] = []  # (arrival, stamp, message)
        self.diags: list[tuple[float, float, dict]] = []  # (arrival, stamp, {robot: (level, message, values)})
        self.q: list[tuple[float, float]] = []  # (arrival, stamp) of q's observation messages
        self.node_diags: list[tuple[float, str]] = []  # (arrival, robot) of the nodes' own /diagnostics (running)
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            now = time.time()
            with self._lock:
                for m in self.readers["pose"].take():
                    self.poses.append((now, M.stamp_of(m.header), m))
                for m in self.readers["q"].take():
                    self.q.append((now, M.stamp_of(m.header)))
                for m in self.readers["diag"].take():
                    if m.status and m.status[0].name.startswith("mutloc node"):
                        self.node_diags += [(now, s.hardware_id) for s in m.status]
                        continue
                    self.diags.append((now, M.stamp_of(m.header), {
                        s.hardware_id: (_level(s.level), s.message, {v.key: v.value for v in s.values})
                        for s in m.status}))
            time.sleep(0.003)

    def wait(self, what: str, stamp_after: float, timeout: float) -> tuple[float, float] | None:
        """The first (arrival, stamp) of ``what`` (``pose`` or ``q``) stamped at or after ``stamp_after``."""
        deadline = time.time() + timeout
        while time.time() < deadline:
            with self._lock:
                rows = self.poses if what == "pose" else self.q
                for row in rows:
                    if row[1] >= stamp_after:
                        return row[0], row[1]
            time.sleep(0.01)
        return None

    def node_ready(self, robot: str, after: float, timeout: float) -> float | None:
        """When the first /diagnostics of ``robot``'s node (published once its detectors are loaded and it
        waits for frames) arrived after ``after``."""
        deadline = time.time() + timeout
        while time.time() < deadline:
            with self._lock:
                got = [a for a, r in self.node_diags if r == robot and a >= after]
            if got:
                return got[0]
            time.sleep(0.01)
        return None

    def last_q_stamp(self) -> float | None:
        with self._lock:
            return self.q[-1][1] if self.q else None

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5.0)
        self.bus.close()


def _level(x) -> int:
    return int.from_bytes(x, "little") if isinstance(x, (bytes, bytearray)) else int(x)


def _launch(procs: list, name: str, cmd: list[str], out: Path) -> subprocess.Popen:
    log = open(out / f"{name}.log", "a", encoding="utf-8")
    p = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    log.close()
    procs.append(p)
    return p


def one(folder: Path, out: Path, wrong: bool, load: str, seed: int, restarts: int, pixel_sigma: float) -> dict:
    """One run (see the module docstring)."""
    rng = np.random.default_rng([seed, 38])
    out.mkdir(parents=True, exist_ok=True)
    rig_path = out / "rig.yaml"
    rig = load_rig(folder / "rig.yaml")
    save_rig(load_rig(perturb_rig(rig.to_dict(), np.random.default_rng([seed, 99]))) if wrong else rig, rig_path)
    truth = truth_of(folder)
    before = load_now()
    procs: list[subprocess.Popen] = []
    events: list[dict] = []
    listener = None
    with cpu_hog(load == "hog"), dds_domain() as lease:
        domain = lease.domain
        common = ["--rig", str(rig_path), "--domain", str(domain), "--loopback"]
        try:
            listener = Listener(domain)
            t_launch = time.time()
            loc = _launch(procs, "localizer", EXE + ["localizer", *common, "--out", str(out / "localizer"),
                                                     "--pixel-sigma", f"{pixel_sigma:g}",
                                                     "--duration", "3600"], out)
            while "localizer: rig_id" not in (out / "localizer.log").read_text(encoding="utf-8"):
                if loc.poll() is not None or time.time() > t_launch + 180:
                    raise RuntimeError(f"the localizer did not start: {(out / 'localizer.log').read_text()[-500:]}")
                time.sleep(0.05)
            ready_s = time.time() - t_launch
            startup = max(4.0, 2.5 * ready_s + 1.0)  # a node's start-up expected (then learnt from each restart)
            start_at = time.time() + startup  # frame 0 of both replays
            node = lambda r, cam, at: EXE + ["node", *common, "--robot", r, "--camera", str(cam), "--realtime",  # noqa
                                             "--loop", "--start-at", f"{at:.6f}", "--no-progress", "--diagnostics"]
            t_nodes = time.time()
            _launch(procs, "p", node("p", folder / "p", start_at), out)
            q = _launch(procs, "q", node("q", folder / "q", start_at), out)
            first = listener.wait("q", start_at, startup + 120)  # (the wrong rig's poses may all be withheld)
            if first is None:
                raise RuntimeError("no observations of q within two minutes of the replays' start")
            ready = [listener.node_ready("q", t_nodes, 1.0)]
            ready = [r - t_nodes for r in ready if r is not None]  # the nodes' start-ups measured
            time.sleep(2.0)
            for k in range(restarts):
                time.sleep(float(rng.uniform(1.0, 2.0)))  # up 1-2 s after a pose came again (a wrong rig: after q came back)
                last_before = listener.last_q_stamp()
                t_kill = time.time()
                kill_process_group(q)
                down = float(rng.uniform(0.5, 4.0))
                time.sleep(max(0.0, t_kill + down - time.time()))
                # the frame due when the new node should be ready (the start-ups measured so far, and a margin),
                # released at its time in the loop
                guess = 1.15 * float(np.median(ready[-5:])) + 0.3 if ready else startup
                t_start = time.time()
                n, j = divmod(int(math.ceil((t_start + guess - start_at) * FPS)), FRAMES)
                at = start_at + n * PERIOD + j / FPS
                cam = rotated(folder / "q", j, out / f"q_{k:02d}")
                q = _launch(procs, "q", node("q", cam, at), out)
                up = listener.node_ready("q", t_start, guess + 180)
                if up is not None:
                    ready.append(up - t_start)
                back = listener.wait("q", at - 1e-4, guess + 180)
                # a pose again (the right rig: within 0.1-0.4 s; a wrong rig's are withheld once it has been tested)
                resumed = None if back is None else listener.wait("pose", back[1], 0.5 if wrong else 30.0)
                late = None if back is None else back[0] - at  # > 0.1: the node was not ready at its first frame
                events.append({"kill": t_kill, "down_s": down, "launched": t_start, "first_due": at,
                               "node_ready_s": None if up is None else up - t_start,
                               "last_q_stamp_before": last_before, "q_back": back, "pose_after": resumed,
                               "late_s": late, "startup_guess_s": guess})
                said = "never" if back is None else (f"{back[0] - t_start:.2f} s after launch (ready after "
                                                      f"{ready[-1]:.2f} s; first frame {late:+.2f} s vs due)")
                print(f"  restart {k + 1}: down {down:.2f} s, q back {said}"
                      + ("" if resumed is None else f", a pose again {resumed[0] - back[0]:.2f} s later"), flush=True)
                if back is None or (resumed is None and not wrong):
                    break
            time.sleep(3.0)
            t_end = time.time()
            stop_process_group([p for p in procs if p.poll() is None], timeout=20.0)
        finally:
            for p in procs:
                kill_process_group(p)
            if listener is not None:
                listener.close()
    after = load_now()
    return analyse(out, listener, events, truth, start_at, first[1], t_end, restarts, before, after, wrong, load)


def _status_of(out: Path):
    """Row status at a capture time (the nearest row within 1 ms) from the localizer's trajectory file."""
    t, st = [], []
    for f in sorted((out / "localizer").glob("*.csv")):
        lines = f.read_text().splitlines()
        if lines and lines[0].startswith("t,status"):
            for ln in lines[1:]:
                a, b = ln.split(",", 2)[:2]
                t.append(float(a))
                st.append(b)
    order = np.argsort(t)
    t, st = np.asarray(t)[order], [st[i] for i in order]

    def at(stamp: float) -> str:
        i = int(np.searchsorted(t, stamp))
        near = [k for k in (i - 1, i) if 0 <= k < len(t) and abs(t[k] - stamp) < 1e-3]
        return st[near[0]] if near else "not in the file"
    return at


def analyse(out, L, events, truth, start_at, first_stamp, t_end, restarts, before, after, wrong, load) -> dict:
    status = _status_of(out)
    # q silent (capture times): its last capture before the kill -> its first after the restart
    # (its last capture: the newest stamp captured before the kill among all q's messages received, also after it)
    q_stamps = np.sort([s for _, s in L.q])
    silent = [(float(q_stamps[q_stamps < e["kill"]][-1]) if (q_stamps < e["kill"]).any() else e["kill"],
               e["q_back"][1] if e["q_back"] else t_end) for e in events]
    # q's node down: the kill -> q's first capture after the restart (the localizer may have it before this
    # process does: a diagnostics message stamped after it may rightly say q is OK)
    kills = [(e["kill"], e["q_back"][1] if e["q_back"] else t_end) for e in events]

    def q_silent(t: float) -> bool:
        return any(a + 1e-4 < t < b - 1e-4 for a, b in silent)

    rows, unmatched = [], 0
    for arrival, stamp, m in L.poses:
        phase = (stamp - start_at) * FPS
        k = int(round(phase))
        if abs(phase - k) > 0.03:
            unmatched += 1
            continue
        R_true, t_true = truth[k % FRAMES]
        p = m.pose.pose
        R = matrix_from_quaternion_xyzw(np.array([p.orientation.x, p.orientation.y, p.orientation.z,
                                                  p.orientation.w]))
        t = np.array([p.position.x, p.position.y, p.position.z])
        cov = spec_covariance(m.pose.covariance)
        e = np.concatenate([so3_log(R @ R_true.T), t - t_true])
        nees = float(e @ np.linalg.solve(cov, e))
        rows.append({"stamp": stamp, "latency": arrival - stamp, "nees": nees,
                     "err_cm": 100 * float(np.linalg.norm(t - t_true)),
                     "sigma_cm": 100 * float(np.sqrt(np.trace(cov[3:, 3:]))),
                     "status": status(stamp), "q_silent": q_silent(stamp)})
    backs = sorted(e["q_back"][1] for e in events if e["q_back"])
    for r in rows:  # how long after q's node came back (None: before the first restart)
        r["after_q_back_s"] = min((r["stamp"] - b for b in backs if b <= r["stamp"]), default=None)
        r["q_silent_for_s"] = next((r["stamp"] - a for a, b in silent if a + 1e-4 < r["stamp"] < b - 1e-4), None)
    (out / "poses.json").write_text(json.dumps({"start_at": start_at, "events": events, "rows": rows, "q": L.q,
                                                "diagnostics": [(a, s, {r: v[:2] for r, v in st.items()})
                                                                for a, s, st in L.diags]}))
    beyond = [r for r in rows if r["nees"] > FIVE_SIGMA_NEES]
    # frame instants of the run (from the first pose to the end), q up / q silent
    instants = np.arange(math.ceil((first_stamp - start_at) * FPS), math.floor((t_end - 1.0 - start_at) * FPS))
    inst_t = start_at + instants / FPS
    silent_mask = np.array([q_silent(t) for t in inst_t])
    stamps_up = {round(r["stamp"], 4) for r in rows if not r["q_silent"] and r["stamp"] <= inst_t[-1]}
    stamps_down = {round(r["stamp"], 4) for r in rows if r["q_silent"]}
    # diagnostics while q's node was down (kill -> q's first message received), by q's silence then
    diag_q, diag_p, unnamed = Counter(), Counter(), []
    for arrival, stamp, st in L.diags:
        i = next((i for i, (a, b) in enumerate(kills) if a <= stamp <= b), None)
        if i is None or "q" not in st:
            continue
        age = stamp - silent[i][0]  # q silent for this long (its last capture -> the diagnostics' stamp)
        bucket = "<0.5 s" if age < WARN_AFTER else "0.5-1 s" if age <= MAX_COAST else "> 1 s"
        diag_q[f"{bucket}:{LEVELS[st['q'][0]]}"] += 1
        diag_p[f"{bucket}:{LEVELS[st['p'][0]]}"] += 1
        if bucket == "> 1 s" and st["q"][0] != M.STALE:
            unnamed.append(st["q"][:2])
    gaps = [b - a for (a, b), e in zip(silent, events) if e["q_back"]]
    lat = [r["latency"] for r in rows]
    loc_log = (out / "localizer.log").read_text(encoding="utf-8").strip().splitlines()
    summary = [ln for ln in loc_log if "records fused" in ln][-1:]
    return {
        "rig": "1-2 cm off" if wrong else "right", "load": load, "load_average_before": before,
        "load_average_after": after, "seconds": t_end - first_stamp,
        "restarts": len(events), "restarts_planned": restarts,
        "restarts_picked_up": sum(1 for e in events if e["q_back"] and e["pose_after"]),
        "down_s_median": float(np.median([e["down_s"] for e in events])) if events else None,
        "gap_s_median": float(np.median(gaps)) if gaps else None, "gap_s_max": max(gaps, default=None),
        "pose_again_after_q_back_s_max": max((e["pose_after"][0] - e["q_back"][0] for e in events
                                              if e["pose_after"]), default=None),
        "node_ready_s_median": float(np.median([e["node_ready_s"] for e in events if e["node_ready_s"]]))
        if any(e["node_ready_s"] for e in events) else None,
        "first_frames_late_s_max": max((e["late_s"] for e in events if e["late_s"] is not None), default=None),
        "poses": len(rows), "poses_not_on_a_frame": unmatched,
        "statuses": dict(Counter(r["status"] for r in rows)),
        "beyond_5_sigma": len(beyond), "beyond_by_status": dict(Counter(r["status"] for r in beyond)),
        "beyond_worst_err_cm": max((r["err_cm"] for r in beyond), default=None),
        "err_cm_median": float(np.median([r["err_cm"] for r in rows])) if rows else None,
        "err_cm_max": max((r["err_cm"] for r in rows), default=None),
        "poses_per_frame_q_up": len(stamps_up) / max(1, int((~silent_mask).sum())),
        "poses_while_q_silent": len([r for r in rows if r["q_silent"]]),
        "q_silent_for_s_max_of_a_pose": max((r["q_silent_for_s"] for r in rows if r["q_silent"]), default=None),
        "pose_stamps_per_frame_q_silent": len(stamps_down) / max(1, int(silent_mask.sum())),
        "latency_ms_p50": 1e3 * float(np.percentile(lat, 50)) if lat else None,
        "latency_ms_p99": 1e3 * float(np.percentile(lat, 99)) if lat else None,
        "diagnostics_q_while_down": dict(sorted(diag_q.items())),
        "diagnostics_p_while_down": dict(sorted(diag_p.items())),
        "q_silent_over_1s_not_stale": len(unnamed), "not_stale_examples": unnamed[:3],
        "localizer_said": summary,
    }


KEYS = ("restarts_picked_up", "gap_s_median", "poses", "beyond_5_sigma", "poses_per_frame_q_up",
        "poses_while_q_silent", "q_silent_over_1s_not_stale", "err_cm_median", "latency_ms_p50", "latency_ms_p99")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=1, help="runs per rig and load (medians reported)")
    ap.add_argument("--restarts", type=int, default=20)
    ap.add_argument("--pixel-sigma", type=float, default=0.05,
                    help="the localizer's --pixel-sigma (default 0.05: the detector's error on these renders is "
                         "0.015 / 0.038 px RMS in u / v; the localizer's default, 1 px, makes every covariance ~25x "
                         "too wide)")
    ap.add_argument("--first-seed", type=int, default=0, help="runs use seeds from this one (down times, wrong rig)")
    ap.add_argument("--load", nargs="+", choices=("idle", "hog"), default=["idle", "hog"])
    ap.add_argument("--rig", nargs="+", choices=("right", "wrong"), default=["right", "wrong"])
    ap.add_argument("--work", help="keep the rendered sequence (and each run's logs) here")
    ap.add_argument("--out", default=result_file("node_restarts.json"))
    args = ap.parse_args(argv)
    info = machine()
    results: dict = {"machine": info, "command": " ".join(["python", *sys.argv]), "restarts": args.restarts,
                     "pixel_sigma": args.pixel_sigma,
                     "size": list(SIZE), "fps": FPS, "configurations": {}}
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(args.work) if args.work else Path(tmp)
        folder = render(work)
        for which in args.rig:
            for load in args.load:
                label = f"rig {which}, {load}"
                runs = []
                for seed in range(args.first_seed, args.first_seed + args.runs):
                    print(f"{label}, run {seed + 1}:", flush=True)
                    r = one(folder, work / f"run-{which}-{load}-{seed}-{int(time.time())}", which == "wrong", load,
                            seed, args.restarts, args.pixel_sigma)
                    runs.append(r)
                    print(json.dumps(r), flush=True)
                med = {k: (float(np.median([r[k] for r in runs if r[k] is not None]))
                           if any(r[k] is not None for r in runs) else None) for k in KEYS}
                results["configurations"][label] = {"median": med, "runs": runs}
                print(f"{label}: median of {len(runs)}: " + ", ".join(f"{k} {v if v is None else round(v, 3)}"
                                                                      for k, v in med.items()), flush=True)
    info["load_average_at_end"] = load_now()
    Path(args.out).write_text(json.dumps(results, indent=1) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

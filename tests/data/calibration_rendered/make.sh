#!/bin/sh
# Regenerates this folder's files (see README.md): renders, tracks, keeps a small log.
set -e
HERE=$(cd "$(dirname "$0")" && pwd)
D=${1:-$(mktemp -d)}
mutloc simulate --robots 3 --markers tags --frames 40 --seed 0 --no-progress --out "$D"
python - "$D" <<'PY'
import sys
import numpy as np
from mutloc import load_rig, save_rig
from mutloc.sim.calibration import perturb_rig
d = sys.argv[1]
truth = load_rig(f"{d}/rig.yaml").to_dict()
save_rig(perturb_rig(truth, np.random.default_rng([0, 27]), 0.01, 0.02, rotation_deg=2.0), f"{d}/rig_measured.yaml")
PY
mutloc track --rig "$D/rig_measured.yaml" --stream r0="$D/r0" --stream r1="$D/r1" --stream r2="$D/r2" \
    --observations-out "$D/log.jsonl" --out "$D/trk" --no-progress
python - "$D" "$HERE" <<'PY'
import json, sys
d, here = sys.argv[1], sys.argv[2]
rows = [json.loads(line) for line in open(f"{d}/log.jsonl", encoding="utf-8")][0::2]  # the even frames
with open(f"{here}/log.jsonl", "w", encoding="utf-8") as f:
    for r in rows:
        r["observations"] = {o: {m: [round(u, 3), round(v, 3)] for m, (u, v) in seen.items()}
                             for o, seen in r["observations"].items()}
        f.write(json.dumps(r, separators=(",", ":")) + "\n")
PY
cp "$D/rig.yaml" "$HERE/rig_true.yaml"
cp "$D/rig_measured.yaml" "$HERE/rig_measured.yaml"

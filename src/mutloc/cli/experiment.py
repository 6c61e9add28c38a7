"""``mutloc experiment``: reproduce one of the paper's experiments."""

from __future__ import annotations

import argparse

ORDER = 60

EXPERIMENTS = ["noise"]


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register ``experiment``."""
    p = subparsers.add_parser(
        "experiment",
        help="reproduce one of the paper's experiments (results.json, report.md, plots)",
        description=(
            "Run one of the paper's experiments and write OUT/NAME/results.json, report.md and plots. "
            "noise: simulation with Gaussian noise on the detected ball centres (paper Sec. V-B)."
        ),
    )
    p.add_argument("name", choices=EXPERIMENTS, metavar="NAME", help=f"experiment ({', '.join(EXPERIMENTS)})")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory (NAME/ is created in it)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0); same seed, same results")
    p.add_argument("--quick", action="store_true", help="a small, fast variant (smoke test, not for the paper)")
    p.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar")
    return p


def run(args: argparse.Namespace) -> int:
    """Run the named experiment and print where the report is."""
    import shlex
    from pathlib import Path

    cmd = ["mutloc", "experiment", args.name, "--out", args.out, "--seed", str(args.seed)]
    if args.quick:
        cmd.append("--quick")
    command = " ".join(shlex.quote(c) for c in cmd)
    if args.name == "noise":
        from ..experiments.noise import QUICK, run_noise

        kwargs = dict(QUICK) if args.quick else {}
        run_noise(args.out, seed=args.seed, progress=args.progress, command=command, **kwargs)
    print(Path(args.out) / args.name / "report.md")
    return 0

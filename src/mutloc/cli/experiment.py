"""``mutloc experiment``: reproduce the paper's experiments."""

from __future__ import annotations

import argparse

from ._common import PROGRESS, SEED

ORDER = 60

EXPERIMENTS = ["noise", "localization", "reconstruction", "calibration", "team", "all"]


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register ``experiment``."""
    p = subparsers.add_parser(
        "experiment", parents=[SEED, PROGRESS],
        help="reproduce the paper's experiments (results.json, report.md, plots)",
        description=(
            "Run one of the paper's experiments and write OUT/NAME/results.json, report.md and plots; "
            "'all' runs every one and writes OUT/report.md. "
            "noise: Gaussian noise on the detected ball centres (Sec. V-B); "
            "localization: grid of positions, mutual localization against a one-sided tag, Bundler (COLMAP "
            "structure from motion over every image), two-frame egomotion and the Dugas closed form "
            "(Sec. V-A, Table II); "
            "reconstruction: points triangulated with each method's poses (Sec. V-C); "
            "calibration (not in 'all'): marker self-calibration from simulated mutual observations, measured "
            "rig perturbed by 1-2 cm; "
            "team (not in the paper, not in 'all'): 3-10 robots, joint versus chained pairwise estimates and "
            "the joint Cramer-Rao bound."
        ),
    )
    p.add_argument("name", choices=EXPERIMENTS, metavar="NAME", help=f"experiment ({', '.join(EXPERIMENTS)})")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory (NAME/ is created in it)")
    p.add_argument("--quick", action="store_true", help="a small, fast variant (smoke test, not for the paper)")
    return p


def run(args: argparse.Namespace) -> int:
    """Run the named experiment(s) and print where the report is."""
    import shlex
    from pathlib import Path

    from ..experiments.report import quick_kwargs, run_all, runner

    cmd = ["mutloc", "experiment", args.name, "--out", args.out, "--seed", str(args.seed)]
    if args.quick:
        cmd.append("--quick")
    command = " ".join(shlex.quote(c) for c in cmd)
    if args.name == "all":
        run_all(args.out, seed=args.seed, quick=args.quick, progress=args.progress, command=command)
        print(Path(args.out) / "report.md")
        return 0
    kwargs = quick_kwargs(args.name) if args.quick else {}
    runner(args.name)(args.out, seed=args.seed, progress=args.progress, command=command, **kwargs)
    print(Path(args.out) / args.name / "report.md")
    return 0

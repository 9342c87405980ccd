"""Run the whole pipeline on the bundled sample scenes and write a report.

Simulates a chessboard session and two anomaly recordings (rain on cam1,
dust with the sides swapped), calibrates, ingests, builds a dataset,
pretrains on synthetic drops, fine-tunes, evaluates and runs a small
accuracy-versus-time tradeoff, then writes OUT/report.md and OUT/report.html.
Each stage prints the equivalent `lenspair` command. A rerun reuses finished
stages. About 10-15 minutes on a 2-core CPU with the default budget.

Example:
  lenspair demo --out demo_out
"""

import argparse
from pathlib import Path

from lenspair.demo import QUICK, Budget, run_demo


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``lenspair demo``."""
    parser.add_argument("--out", type=Path, default=Path("demo_out"), help="output folder")
    parser.add_argument(
        "--quick",
        action="store_true",
        help="tiny budget: every stage runs in about a minute, nothing is learnt",
    )


def run(args: argparse.Namespace) -> int:
    """Run the demo; returns 0 on success."""
    report = run_demo(args.out, QUICK if args.quick else Budget())
    print(f"lenspair demo: report written to {report} (and {report.with_suffix('.html')})")
    return 0

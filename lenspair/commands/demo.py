"""Run the whole pipeline on the bundled sample scenes and write a report.

Simulates a chessboard session and three anomaly recordings (light and
heavy rain on cam1, dust with the sides swapped), calibrates, ingests,
builds a dataset, pretrains on synthetic drops, fine-tunes, evaluates,
runs a small accuracy-versus-time tradeoff and restores one recording, then
writes OUT/report.md and OUT/report.html. Each stage prints the equivalent
`lenspair` command. A rerun reuses finished stages (a stage whose inputs or
output changed runs again, and so does every stage after it; a stopped
training continues where it stopped). One demo at a time writes to OUT,
which must be new, empty or an earlier demo's: the demo replaces the
folders it writes there. The default budget is sized
for under a quarter of an hour on a 2-core CPU.

Example:
  lenspair demo --out demo_out
"""

import argparse
import shlex
from pathlib import Path

from lenspair.commands.argtypes import out_folder
from lenspair.demo import QUICK, Budget, check_out, run_demo


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``lenspair demo``."""
    parser.add_argument(
        "--out",
        type=out_folder,
        default=Path("demo_out"),
        help="output folder (default: demo_out in the current folder)",
    )
    parser.add_argument(
        "--quick",
        action="store_true",
        help="tiny budget: every stage runs, nothing is learnt (the end-to-end test)",
    )


def interrupt_hint(args: argparse.Namespace) -> str:
    """After Ctrl-C: the same command again goes on from the stage it stopped in."""
    quick = " --quick" if args.quick else ""
    out = shlex.quote(str(args.out))
    return f"rerun lenspair demo --out {out}{quick} to resume from the stage it stopped in"


def run(args: argparse.Namespace) -> int:
    """Run the demo; returns 0 on success."""
    check_out(args.out.resolve())  # a refused folder is not written to: say so first
    print(f"lenspair demo: writing to {args.out.resolve()}", flush=True)
    report = run_demo(args.out, QUICK if args.quick else Budget())
    print(f"lenspair demo: report written to {report} (and {report.with_suffix('.html')})")
    return 0

"""Run every benchmark: ``python -m benchmarks [--out DIR] [--only NAME ...]``.

Each ``benchmarks/bench_*.py`` module has a ``main(argv) -> int`` that prints a
Markdown table and, with ``--out``, writes ``<name>.json``. Numbers are
medians, and speeds are reported as ratios to a floor or peak measured in the
same run, because shared machines are noisy.
"""

import argparse
import importlib
import pkgutil
import sys
import time
import traceback
from pathlib import Path

import torch

import benchmarks


def main(argv: list[str] | None = None) -> int:
    """Run the selected benchmarks in turn; returns non-zero if any failed."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks", description=__doc__)
    parser.add_argument("--out", type=Path, default=None, help="folder for JSON results")
    parser.add_argument("--only", nargs="+", default=None, help="names, e.g. effects model")
    args = parser.parse_args(argv)
    names = sorted(
        m.name for m in pkgutil.iter_modules(benchmarks.__path__) if m.name.startswith("bench_")
    )
    if args.only is not None:
        known = {n.removeprefix("bench_") for n in names}
        wanted = {name.removeprefix("bench_") for name in args.only}
        if unknown := sorted(wanted - known):  # ran nothing and said nothing
            parser.error(
                f"--only: no benchmark named {', '.join(unknown)}; choose from "
                f"{', '.join(sorted(known))}"
            )
        names = [n for n in names if n.removeprefix("bench_") in wanted]
    if args.out is not None and args.out.exists() and not args.out.is_dir():
        parser.error(f"--out {args.out}: exists and is not a folder")  # before hours of work
    failed = []
    threads = torch.get_num_threads()
    for name in names:
        # Some benchmarks set torch's thread count (bench_detector: 1); the next
        # one must start from the machine's, not inherit it.
        torch.set_num_threads(threads)
        print(f"\n## {name}\n", flush=True)
        start = time.perf_counter()
        module = importlib.import_module(f"benchmarks.{name}")
        try:
            code = module.main([] if args.out is None else ["--out", str(args.out)])
        except SystemExit as stop:  # argparse's error exit: count it, run the others
            code = stop.code if isinstance(stop.code, int) else 1
        except Exception:  # one benchmark's failure must not cost the others their run
            traceback.print_exc()
            code = 1
        print(f"\n({name} took {time.perf_counter() - start:.0f} s)", flush=True)
        if code:
            failed.append(name)
    if failed:
        print(f"failed: {', '.join(failed)}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())

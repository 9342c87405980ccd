"""Run every benchmark: ``python -m benchmarks [--out DIR] [--only NAME ...]``.

Each ``benchmarks/bench_*.py`` module has a ``main(argv) -> int`` that prints a
Markdown table and, with ``--out``, writes ``<name>.json``. Numbers are
medians, and speeds are reported as ratios to a floor or peak measured in the
same run, because shared machines are noisy.

Each benchmark runs in its own process (``python -m benchmarks.bench_NAME``),
as it does alone: process-wide settings one of them makes (the allocator
tuning of :func:`lenspair.model.evaluation.latency.tune_allocator`, torch's
thread count, oneDNN's kernel caches) must not carry over into the next one's
measurements. A benchmark that fails (non-zero exit, a crash, argparse's exit
2) is named at the end and the others still run; the exit status is 1 if any
failed.

Every JSON file a benchmark writes into ``--out`` gets a ``benchmark_run``
entry: the id of this invocation and the machine (CPU, cores, torch threads,
oneDNN's ISA cap), so that ``benchmarks.readme_results`` can tell files of one
run from files of several (:func:`stamp`), and the benchmarks that started
while other processes kept the CPU busy (``busy_at_start``: CPU pressure at
or above :data:`benchmarks.machine.BUSY_PRESSURE`), whose ratios it refuses.
"""

import argparse
import json
import os
import pkgutil
import secrets
import subprocess
import sys
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import torch

import benchmarks
from benchmarks import RUN_KEY
from benchmarks.machine import BUSY_PRESSURE, cpu_pressure, pressure_avg10
from lenspair.model.precision import onednn_isa_cap, read_cpu_flags

ROOT = Path(benchmarks.__file__).resolve().parents[1]
"""The folder that holds the ``benchmarks`` package (and ``tests``, which one imports)."""


def run_record() -> dict[str, Any]:
    """A fresh run id and the machine it runs on: the ``benchmark_run`` entry."""
    started = datetime.now(UTC)
    return {
        "id": f"{started:%Y%m%dT%H%M%SZ}-{secrets.token_hex(3)}",
        "started": started.isoformat(timespec="seconds"),
        "cpu": read_cpu_flags()[0],
        "cores": os.cpu_count(),
        "threads": torch.get_num_threads(),
        "onednn_max_cpu_isa": onednn_isa_cap(),
    }


def command(name: str, out: Path | None) -> list[str]:
    """The command line that runs benchmark ``name`` (``bench_...``) in a process of its own."""
    out_option = [] if out is None else ["--out", str(out)]
    return [sys.executable, "-m", f"benchmarks.{name}", *out_option]


def _json_files(out: Path | None) -> dict[Path, tuple[int, int]]:
    """``{path: (mtime_ns, size)}`` of the JSON files directly in ``out``."""
    if out is None or not out.is_dir():
        return {}
    return {path: (path.stat().st_mtime_ns, path.stat().st_size) for path in out.glob("*.json")}


def stamp(out: Path | None, before: dict[Path, tuple[int, int]], run: dict[str, Any]) -> list[Path]:
    """Add ``run`` to each JSON file in ``out`` written since ``before``; returns them."""
    stamped = []
    for path, state in sorted(_json_files(out).items()):
        if before.get(path) == state:
            continue
        try:
            record = json.loads(path.read_text())
        except (OSError, ValueError) as error:
            print(f"{path}: not stamped with the run id ({error})", file=sys.stderr)
            continue
        if not isinstance(record, dict):
            print(f"{path}: not stamped with the run id (not a JSON object)", file=sys.stderr)
            continue
        record[RUN_KEY] = run
        path.write_text(json.dumps(record, indent=2) + "\n")
        stamped.append(path)
    return stamped


def _environment() -> dict[str, str]:
    """This process's environment, with the ``benchmarks`` package importable from any folder."""
    paths = [str(ROOT), *filter(None, os.environ.get("PYTHONPATH", "").split(os.pathsep))]
    return {**os.environ, "PYTHONPATH": os.pathsep.join(paths)}


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
    run = run_record()
    print(f"benchmark run {run['id']}", flush=True)
    failed = []
    environment = _environment()
    for name in names:
        print(f"\n## {name}\n", flush=True)
        pressure = pressure_avg10(cpu_pressure())
        if pressure is not None and pressure >= BUSY_PRESSURE:  # recorded in its own file too
            run.setdefault("busy_at_start", {})[name] = pressure
            print(f"warning: {name} starts on a busy CPU (pressure {pressure:.0f} %)", flush=True)
        start = time.perf_counter()
        before = _json_files(args.out)
        try:
            code = subprocess.run(command(name, args.out), env=environment, check=False).returncode
        except OSError as error:  # the interpreter could not be started: count it, run the others
            print(f"{name}: {error}", file=sys.stderr)
            code = 1
        stamp(args.out, before, run)
        print(f"\n({name} took {time.perf_counter() - start:.0f} s)", flush=True)
        if code:
            failed.append(name)
    if busy := run.get("busy_at_start"):
        print(
            f"warning: {', '.join(busy)} started with other processes keeping the CPU busy: "
            "their ratios are inflated, and benchmarks.readme_results refuses the run; "
            "rerun on a quiet machine",
            file=sys.stderr,
        )
    if failed:
        print(f"failed: {', '.join(failed)}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())

"""bf16 against fp32 with and without oneDNN's instruction cap, in one run.

    python -m benchmarks.bench_isa_cap [--runs 15] [--cap AVX512_CORE_VNNI] [--out DIR]

Times one GEA-sized 3x3 convolution (32 to 32 channels, 270x180,
channels-last, batch 1, one thread) in fp32 and under bf16 autocast, in two
child processes: one as the machine is, one with ``ONEDNN_MAX_CPU_ISA=CAP``
(oneDNN reads the cap when it starts, so it takes a new process). Prints the
bf16/fp32 ratio of each, medians of interleaved runs, and what the precision
probe (:func:`lenspair.model.precision.choose_precision`) decides in each;
with ``--out``, also ``isa_cap.json``.

On a CPU with native bf16 the cap shows what a CPU without it does: oneDNN
emulates bf16 through fp32 conversions (the Xeon without ``avx512_bf16`` of
issue #11 measured 2.6x slower than fp32 for a whole training step), and
``auto`` must then stay at fp32.
"""

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import torch

from benchmarks.machine import median_ms, round_robin
from lenspair.commands.argtypes import positive_int
from lenspair.model.precision import choose_precision

CHANNELS, HEIGHT, WIDTH = 32, 180, 270
KERNEL = f"3x3 conv {CHANNELS}->{CHANNELS} {WIDTH}x{HEIGHT}, 1 thread"
"""What is timed, as the table and ``isa_cap.json`` name it."""


def child(runs: int) -> dict[str, object]:
    """In this process: the medians and the probe's decision (the cap is this process's own)."""
    torch.set_num_threads(1)
    x = torch.randn(1, CHANNELS, HEIGHT, WIDTH).to(memory_format=torch.channels_last)
    conv = torch.nn.Conv2d(CHANNELS, CHANNELS, 3, padding=1)
    conv = conv.to(memory_format=torch.channels_last)  # type: ignore[call-overload]

    def bf16() -> None:
        with torch.autocast("cpu", torch.bfloat16):
            conv(x)

    with torch.inference_mode():
        times = round_robin({"fp32": lambda: conv(x), "bf16": bf16}, runs, 3, time.perf_counter)
    decision = choose_precision("auto", torch.device("cpu"), "train")
    medians = {name: median_ms(samples) for name, samples in times.items()}
    return {"median_ms": medians, "auto": decision.precision, "reason": decision.reason}


def measure(runs: int, cap: str | None) -> dict[str, object]:
    """:func:`child` in a new process (``cap``: None = as the machine is)."""
    env = {
        k: v for k, v in os.environ.items() if k not in ("ONEDNN_MAX_CPU_ISA", "DNNL_MAX_CPU_ISA")
    }
    if cap is not None:
        env["ONEDNN_MAX_CPU_ISA"] = cap
    command = [sys.executable, "-m", "benchmarks.bench_isa_cap", "--child", "--runs", str(runs)]
    out = subprocess.run(command, env=env, capture_output=True, text=True, check=True)
    result: dict[str, object] = json.loads(out.stdout.strip().splitlines()[-1])
    return result


def main(argv: list[str] | None = None) -> int:
    """Command line (module docstring); returns the exit code."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--runs", type=positive_int, default=15)
    parser.add_argument("--cap", default="AVX512_CORE_VNNI")
    parser.add_argument("--out", type=Path, default=None, help="folder for isa_cap.json")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        print(json.dumps(child(args.runs)))
        return 0
    load = os.getloadavg()[0]
    start = time.monotonic()
    print("| oneDNN ISA | fp32 ms | bf16 ms | bf16 / fp32 | `auto` trains at |")
    print("|---|---|---|---|---|")
    rows = []
    for cap in (None, args.cap):
        result = measure(args.runs, cap)
        medians = result["median_ms"]
        assert isinstance(medians, dict)
        ratio = medians["bf16"] / medians["fp32"]
        rows.append({"cap": cap, "bf16_over_fp32": ratio, **result})
        print(
            f"| {cap or 'as the machine is'} | {medians['fp32']:.2f} | {medians['bf16']:.2f} "
            f"| {ratio:.2f} | {result['auto']} |"
        )
    end_load = os.getloadavg()[0]
    print(
        f"\n{KERNEL}, median of {args.runs}; load average "
        f"{load:.2f} -> {end_load:.2f}; {time.monotonic() - start:.0f} s"
    )
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        payload = {
            "kernel": KERNEL,
            "runs": args.runs,
            "load_average": [load, end_load],
            "rows": rows,
        }
        (args.out / "isa_cap.json").write_text(json.dumps(payload, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

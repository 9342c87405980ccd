"""CPU latency of the restoration network against the machine's measured peak.

``python -m benchmarks.bench_model [--out DIR]``: GEA, mono, 540x360, batch 1,
``torch.inference_mode``, after warm-up. Reports

* the fp32 matmul peak measured in the same run, as the best of three
  GEMM-like kernels: ``torch.mm`` 2048^3 (MKL, which takes a slow path on
  this AMD CPU), a oneDNN 1x1 convolution (a plain 4096x512x512 GEMM) and a
  oneDNN 3x3 convolution (an implicit 4096x256x2304 GEMM, the kernel family
  the network runs on); the roofline is ``FLOPs / best``;
* the model's FLOPs (2 per MAC, :mod:`lenspair.model.networks.complexity`);
* fp32 latency (NCHW and channels-last) and its ratio to the roofline
  ``FLOPs / peak``;
* bf16 latency for autocast and for bf16 weights, each NCHW and
  channels-last, the fastest one named, and the PSNR of its output against
  the fp32 output (where the CPU only emulates bf16, a few runs each:
  :data:`EMULATED_RUNS`);
* with ``--compile``, also ``torch.compile`` (inductor, offline, C++ code
  generation with gcc, frozen weights) of the channels-last models;
* each configuration's ratio to the roofline of its own precision: fp32
  rows to the fp32 peak, bf16 rows (autocast and bf16 weights) to the peak
  of the same three kernels in bf16, measured where bf16 is native; where it
  is emulated no bf16 peak is measured and those cells stay empty (an fp32
  peak would give ratios below 1);
* the same with glibc's default allocator, and, as a measure that other
  processes disturb much less, the CPU time of one forward pass on one
  thread against a one-thread peak measured the same way;
* where the fp32 time goes: a per-layer profile (``torch.profiler``, by
  operator and input shape, :mod:`benchmarks.model_profile`);
* GEA against DeRaindrop's generator (:mod:`benchmarks.deraindrop`) at
  720x480 RGB in the same run, and which precisions are native on this CPU
  (:mod:`lenspair.model.precision`), with oneDNN's ISA cap
  (``ONEDNN_MAX_CPU_ISA``) and the decision's reason; configurations at a
  precision that is not native are marked emulated.

Allocator: by default glibc serves the large activation tensors with fresh
``mmap`` calls and returns them on free, so every forward pass page-faults
all of its memory again (measured 2-3x slower). The main numbers are taken
after ``mallopt`` raises the mmap threshold to 32 MiB and disables trimming,
which has the effect of deploying with jemalloc/tcmalloc, as Intel
recommends for PyTorch on CPU. The tuning is process-wide and cannot be
undone: where it was made before :func:`run` (another benchmark in the same
process), the default-allocator figures are not measured and say so.

Configurations are timed round-robin (interleaved) so that load from other
processes hits them all alike; medians are quoted, and the load average and
CPU pressure at the start and end of the run are recorded.
"""

import argparse
import contextlib
import copy
import json
import os
import platform
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import torch

from benchmarks.machine import cpu_pressure, median_ms, round_robin
from benchmarks.machine import peaks as measure_peaks
from benchmarks.model_profile import deraindrop_comparison, layer_profile
from benchmarks.model_report import model_table
from benchmarks.model_roofline import (
    best_fields,
    precision_of,
    roofline_fields,
    single_thread_fields,
)
from lenspair.commands.argtypes import positive_int
from lenspair.model.evaluation.latency import tune_allocator
from lenspair.model.networks.complexity import describe
from lenspair.model.networks.variants import AnomalyMitigator, build_model
from lenspair.model.precision import (
    choose_precision,
    onednn_isa_cap,
    probe_hardware,
    read_cpu_flags,
)

HEIGHT, WIDTH = 360, 540
EMULATED_RUNS = 3
"""Timed runs of each bf16 configuration where bf16 is emulated: on an AVX2-only EPYC
one emulated pass took about 2 s (9.5x fp32), and 40 of each kept the benchmark past
45 minutes (docs/results/cpu_amd_epyc_avx2.md); a few show the ratio."""

Context = Callable[[], contextlib.AbstractContextManager[None]]
Configuration = tuple[Callable[[torch.Tensor], torch.Tensor], torch.Tensor, Context]
"""What one configuration times: the network's ``restore``, its input and a context."""
Call = Callable[[], object]


def structured_image() -> torch.Tensor:
    """A deterministic mono test frame: gradients, stripes, a disc, fine noise."""
    yy, xx = torch.meshgrid(
        torch.linspace(0, 1, HEIGHT), torch.linspace(0, 1, WIDTH), indexing="ij"
    )
    image = 0.4 + 0.3 * xx * yy + 0.15 * torch.sin(40 * xx) * torch.cos(25 * yy)
    image[((xx - 0.6) ** 2 + (yy - 0.4) ** 2) < 0.02] = 0.95
    noise = torch.rand(HEIGHT, WIDTH, generator=torch.Generator().manual_seed(0))
    return (image + 0.03 * noise).clamp(0, 1)[None, None]


def untrained_model() -> AnomalyMitigator:
    """GEA with its zero-initialised heads randomised, so outputs differ from inputs."""
    torch.manual_seed(0)
    model = build_model("GEA", 1)
    assert model.enhancer is not None
    with torch.no_grad():
        for head in (model.generator.head, model.enhancer.fuse):
            head.weight.normal_(0.0, 0.002)
    return model.eval()


def _channels_last(model: AnomalyMitigator) -> AnomalyMitigator:
    """Move 4-D weights to channels-last (oneDNN's fast layout on CPU)."""
    return model.to(memory_format=torch.channels_last)  # type: ignore[call-overload,no-any-return]


@contextlib.contextmanager
def _nothing() -> Iterator[None]:
    yield


def _autocast() -> contextlib.AbstractContextManager[None]:
    return torch.autocast("cpu", dtype=torch.bfloat16)


def _configs(model: AnomalyMitigator, compile_models: bool) -> dict[str, Configuration]:
    image = structured_image()
    image_cl = image.contiguous(memory_format=torch.channels_last)
    model_cl = _channels_last(copy.deepcopy(model))
    model_bf16 = copy.deepcopy(model).to(torch.bfloat16)
    model_bf16_cl = _channels_last(copy.deepcopy(model_bf16))
    image_bf16 = image.to(torch.bfloat16)
    image_bf16_cl = image_bf16.contiguous(memory_format=torch.channels_last)
    configs: dict[str, Configuration] = {
        "fp32 NCHW": (model.restore, image, _nothing),
        "fp32 channels-last": (model_cl.restore, image_cl, _nothing),
        "bf16 autocast NCHW": (model.restore, image, _autocast),
        "bf16 autocast channels-last": (model_cl.restore, image_cl, _autocast),
        "bf16 weights NCHW": (model_bf16.restore, image_bf16, _nothing),
        "bf16 weights channels-last": (model_bf16_cl.restore, image_bf16_cl, _nothing),
    }
    if compile_models:
        # only where compiled forms are timed: importing inductor takes about a second
        import torch._inductor.config as inductor_config

        inductor_config.freezing = True
        configs["fp32 channels-last compiled"] = (
            torch.compile(model_cl.restore),
            image_cl,
            _nothing,
        )
        configs["bf16 weights channels-last compiled"] = (
            torch.compile(model_bf16_cl.restore),
            image_bf16_cl,
            _nothing,
        )
    return configs


def _callers(
    configs: dict[str, Configuration],
    outputs: dict[str, torch.Tensor],
) -> dict[str, Call]:
    """One timed call per configuration; each keeps its last output in ``outputs``."""

    def caller(name: str) -> Call:
        network, x, context = configs[name]

        def call() -> object:
            with context():
                outputs[name] = network(x)
            return None

        return call

    return {name: caller(name) for name in configs}


@dataclass
class _Timings:
    """What the timed phase of :func:`run` measured: seconds per call, GFLOP/s per kernel."""

    default_times: dict[str, list[float]]
    times: dict[str, list[float]]
    single_times: dict[str, list[float]]
    peaks: dict[str, float]
    bf16_peaks: dict[str, float]
    single_peaks: dict[str, float]
    single_bf16_peaks: dict[str, float]
    allocator_tuned: bool
    tuned_before: bool


def _measure(
    interleaved: dict[str, Call],
    emulated: dict[str, Call],
    runs: int,
    warmup: int,
    threads: int,
    bf16_native: bool,
) -> _Timings:
    """Time every configuration and the peaks: default malloc, tuned, then one thread."""

    def timed(count: int, warm: int, clock: Callable[[], float]) -> dict[str, list[float]]:
        times = round_robin(interleaved, count, warm, clock)
        return times | round_robin(emulated, min(count, EMULATED_RUNS), min(warm, 1), clock)

    # tune_allocator is cached: a call before this one (another benchmark in this
    # process) has tuned glibc already, and "default malloc" would time the tuned one
    tuned_before = tune_allocator.cache_info().currsize > 0
    peak_runs = max(5, runs // 3)
    bf16_peaks: dict[str, float] = {}
    single_bf16_peaks: dict[str, float] = {}
    with torch.inference_mode():
        torch.set_num_threads(threads)
        default_times = {} if tuned_before else timed(max(5, runs // 2), warmup, time.perf_counter)
        allocator_tuned = tune_allocator()
        peaks = measure_peaks(peak_runs, time.perf_counter)
        if bf16_native:
            bf16_peaks = measure_peaks(peak_runs, time.perf_counter, torch.bfloat16)
        times = timed(runs, warmup, time.perf_counter)
        torch.set_num_threads(1)
        single_peaks = measure_peaks(5, time.thread_time)
        if bf16_native:
            single_bf16_peaks = measure_peaks(5, time.thread_time, torch.bfloat16)
        single_times = timed(max(5, runs // 4), 1, time.thread_time)
        torch.set_num_threads(threads)
    return _Timings(
        default_times=default_times,
        times=times,
        single_times=single_times,
        peaks=peaks,
        bf16_peaks=bf16_peaks,
        single_peaks=single_peaks,
        single_bf16_peaks=single_bf16_peaks,
        allocator_tuned=allocator_tuned,
        tuned_before=tuned_before,
    )


def run(
    runs: int,
    warmup: int,
    threads: int,
    compile_models: bool = False,
    profile_runs: int = 3,
    deraindrop_runs: int = 3,
) -> dict[str, object]:
    """Measure everything; returns the JSON record.

    The rooflines, ratios and targets in it are worked out by
    :mod:`benchmarks.model_roofline`; :func:`benchmarks.model_report.model_table`
    prints it.
    """
    load_start, pressure_start = os.getloadavg(), cpu_pressure()
    model = untrained_model()
    summary = describe(model, (1, HEIGHT, WIDTH))
    outputs: dict[str, torch.Tensor] = {}
    calls = _callers(_configs(model, compile_models), outputs)
    precision = choose_precision("auto", torch.device("cpu"), "infer")
    bf16_native = "bf16" in precision.native
    # Where bf16 is native it stays in the round-robin with fp32, timed alike;
    # where it is emulated, its configurations run apart, a few times each.
    emulated = {} if bf16_native else {n: c for n, c in calls.items() if n.startswith("bf16")}
    interleaved = {name: call for name, call in calls.items() if name not in emulated}
    bf16_runs = min(runs, EMULATED_RUNS) if emulated else runs
    timings = _measure(interleaved, emulated, runs, warmup, threads, bf16_native)
    medians = {name: median_ms(samples) for name, samples in timings.times.items()}
    fp32_name = min((n for n in medians if n.startswith("fp32")), key=medians.__getitem__)
    profile: list[dict[str, object]] = []
    if profile_runs > 0:
        with torch.inference_mode():
            profile = layer_profile(calls[fp32_name], profile_runs)
    deraindrop = deraindrop_comparison(deraindrop_runs) if deraindrop_runs > 0 else {}
    single_ms = {name: median_ms(samples) for name, samples in timings.single_times.items()}
    return {
        "device": platform.processor() or platform.machine(),
        "cpu_model": read_cpu_flags()[0],
        "torch": torch.__version__,
        "threads": threads,
        "runs": runs,
        "warmup": warmup,
        "size": [HEIGHT, WIDTH],
        "variant": "GEA",
        "channels": 1,
        "parameters": summary.parameters,
        "flops": summary.flops,
        "gflops": summary.gflops,
        "allocator_tuned": timings.allocator_tuned,
        "allocator_tuned_before_run": timings.tuned_before,
        **roofline_fields(timings.peaks, timings.bf16_peaks, summary.flops, medians),
        "medians_ms": medians,
        "min_ms": {name: min(samples) * 1e3 for name, samples in timings.times.items()},
        "default_allocator_medians_ms": {
            name: median_ms(samples) for name, samples in timings.default_times.items()
        },
        **best_fields(medians, outputs, summary.flops, timings.peaks),
        **single_thread_fields(
            timings.single_peaks, timings.single_bf16_peaks, single_ms, summary.flops, fp32_name
        ),
        "precision": precision.as_dict(),
        "onednn_max_cpu_isa": onednn_isa_cap(),
        "isa_cap": probe_hardware(torch.device("cpu")).isa_cap,
        "emulated": sorted(name for name in medians if precision_of(name) not in precision.native),
        "bf16_runs": bf16_runs,
        "layer_profile_fp32": profile,
        "deraindrop_720x480_rgb": deraindrop,
        "load_average_start": list(load_start),
        "load_average_end": list(os.getloadavg()),
        "cpu_pressure_start": pressure_start,
        "cpu_pressure_end": cpu_pressure(),
    }


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark, print a Markdown table, optionally write ``model.json``."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks.bench_model", description=__doc__)
    parser.add_argument("--out", type=Path, default=None, help="folder for model.json")
    parser.add_argument(
        "--runs", type=positive_int, default=40, help="timed runs per configuration"
    )
    parser.add_argument("--warmup", type=int, default=5, help="untimed runs per configuration")
    parser.add_argument("--threads", type=int, default=torch.get_num_threads())
    parser.add_argument(
        "--compile", action="store_true", help="also time torch.compile'd models (slow start)"
    )
    parser.add_argument("--profile-runs", type=int, default=3, help="profiled runs (0: none)")
    parser.add_argument(
        "--deraindrop-runs", type=int, default=3, help="720x480 DeRaindrop comparison (0: none)"
    )
    args = parser.parse_args(argv)
    record = run(
        args.runs,
        args.warmup,
        args.threads,
        compile_models=args.compile,
        profile_runs=args.profile_runs,
        deraindrop_runs=args.deraindrop_runs,
    )
    print(model_table(record))
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "model.json").write_text(json.dumps(record, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""int8 inference two ways: ONNX Runtime static quantisation against PyTorch's PT2E.

``python -m benchmarks.bench_int8 [--out DIR] [--runs N]``: GEA, mono,
540x360, batch 1, the mono weights that ship with lenspair (a trained
network: an untrained one's output is nearly its input, and read int8 as
15 dB worse than the trained one does), timed and scored on a held-out
photograph (:data:`lenspair.simulate.natural_images.HELD_OUT`) under the
``ours`` drops, and calibrated on 8 others under other drop draws
(:func:`_frames`: calibration and test frames share no photograph).
Timed round-robin in one run (medians):

* fp32 torch as lenspair deploys it (channels-last, allocator tuned:
  :func:`benchmarks.machine.as_deployed`), the reference output and time.
  The allocator is tuned before anything is timed, so the figures are the
  same whether this runs alone or in ``python -m benchmarks``;
* ONNX Runtime int8: ``quantize_static`` QDQ, per-channel int8 weights,
  uint8 activations (:mod:`lenspair.model.evaluation.quantize`, what
  ``lenspair export --int8`` writes);
* PT2E int8: ``torch.export`` + torchao's ``X86InductorQuantizer`` +
  ``torch.compile`` (inductor; needs a C++ compiler; compile time recorded).

For each: median ms, ratio to fp32, PSNR of its output against fp32's,
and setup seconds (quantisation, compilation). PT2E is skipped, and the
record says why, where torchao or a compiler is missing.
"""

import argparse
import copy
import json
import os
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from benchmarks.bench_model import HEIGHT, WIDTH
from benchmarks.machine import as_deployed
from lenspair.commands.argtypes import positive_int
from lenspair.model.checkpoint import load_model
from lenspair.model.evaluation.onnx_graph import INPUT_NAME
from lenspair.model.evaluation.quantize import open_session, quantize_network
from lenspair.model.metrics import psnr
from lenspair.model.networks.variants import AnomalyMitigator
from lenspair.model.precision import choose_precision, read_cpu_flags
from lenspair.model.training.pretrained import pretrained_weights
from lenspair.simulate.natural_images import HELD_OUT, load_natural_images
from lenspair.simulate.presets import OUR_DROPS
from lenspair.simulate.render import render_effects


def _network() -> AnomalyMitigator:
    """The shipped mono GEA, fp32, in eval mode on the CPU."""
    network = load_model(pretrained_weights(1)).network
    assert isinstance(network, AnomalyMitigator)
    return network


def _frames(count: int) -> tuple[torch.Tensor, list[torch.Tensor]]:
    """The test frame and ``count`` calibration frames, ``(1, 1, H, W)`` in [0, 1].

    Photographs at 540x360 under ``ours`` drops: the test frame is the first
    held-out one, the calibration frames the training photographs in turn,
    each under a drop draw of its own.
    """
    photos = load_natural_images((HEIGHT, WIDTH), 1)
    training = [name for name in photos if name not in HELD_OUT]

    def rendered(name: str, seed: int) -> torch.Tensor:
        obstructed, _ = render_effects(photos[name], OUR_DROPS, np.random.default_rng(seed))
        return torch.from_numpy(obstructed.astype(np.float32) / 255.0)[None, None]

    test = rendered(HELD_OUT[0], 0)
    return test, [rendered(training[k % len(training)], k + 1) for k in range(count)]


def _pt2e(model: torch.nn.Module, calibration: list[torch.Tensor]) -> Callable[[torch.Tensor], Any]:
    from torchao.quantization.pt2e.quantize_pt2e import convert_pt2e, prepare_pt2e
    from torchao.quantization.pt2e.quantizer.x86_inductor_quantizer import (
        X86InductorQuantizer,
        get_default_x86_inductor_quantization_config,
    )

    class Restore(torch.nn.Module):
        def __init__(self, inner: torch.nn.Module) -> None:
            super().__init__()
            self.inner = inner

        def forward(self, x: torch.Tensor) -> torch.Tensor:
            return self.inner(x)[1]  # type: ignore[no-any-return]

    quantizer = X86InductorQuantizer()
    quantizer.set_global(get_default_x86_inductor_quantization_config())
    exported = torch.export.export(Restore(model), (calibration[0],)).module()
    prepared = prepare_pt2e(exported, quantizer)  # type: ignore[arg-type]
    for image in calibration:
        prepared(image)
    converted = convert_pt2e(prepared)
    import torch._inductor.config as inductor_config

    inductor_config.freezing = True
    compiled = torch.compile(converted)
    with torch.no_grad():
        compiled(calibration[0])
    return compiled  # type: ignore[no-any-return]


def run(runs: int, calibration_count: int, pt2e: bool) -> dict[str, Any]:
    """Quantise both ways, time round-robin; returns the JSON record."""
    model = _network()
    image, calibration = _frames(calibration_count)
    model_cl, image_cl = as_deployed(model, image)
    calls: dict[str, Callable[[], Any]] = {"fp32 torch": lambda: model_cl.restore(image_cl)}
    setup: dict[str, float] = {}
    notes: dict[str, str] = {}
    folder = tempfile.TemporaryDirectory(prefix="bench-int8-")
    start = time.perf_counter()
    path = quantize_network(
        model, 1, Path(folder.name) / "int8.onnx", (HEIGHT, WIDTH), [c.numpy() for c in calibration]
    )
    session = open_session(path)
    setup["onnxruntime int8"] = time.perf_counter() - start
    feed = {INPUT_NAME: image.numpy()}
    calls["onnxruntime int8"] = lambda: torch.from_numpy(session.run(None, feed)[0])
    if pt2e:
        start = time.perf_counter()
        try:
            compiled = _pt2e(copy.deepcopy(model), calibration)
            setup["pt2e x86-inductor int8"] = time.perf_counter() - start
            calls["pt2e x86-inductor int8"] = lambda: compiled(image)
        except Exception as exc:  # missing torchao/compiler or an unsupported op: record it
            notes["pt2e x86-inductor int8"] = f"{type(exc).__name__}: {str(exc)[:200]}"
    outputs: dict[str, torch.Tensor] = {}
    times: dict[str, list[float]] = {name: [] for name in calls}
    with torch.inference_mode():
        for name, call in calls.items():
            outputs[name] = call().float()
        for _ in range(runs):
            for name, call in calls.items():
                begin = time.perf_counter()
                call()
                times[name].append((time.perf_counter() - begin) * 1e3)
    medians = {name: statistics.median(values) for name, values in times.items()}
    reference = outputs["fp32 torch"].clamp(0, 1)
    return {
        "cpu_model": read_cpu_flags()[0],
        "torch": torch.__version__,
        "threads": torch.get_num_threads(),
        "runs": runs,
        "calibration_images": calibration_count,
        "network": "shipped mono GEA weights (model/weights/gea_ours_mono.pt)",
        "test_frame": f"{HELD_OUT[0]} (held out) under ours drops",
        "precision": choose_precision("int8", torch.device("cpu"), "infer").as_dict(),
        "medians_ms": medians,
        "speed_vs_fp32": {n: medians["fp32 torch"] / v for n, v in medians.items()},
        "psnr_vs_fp32_db": {
            n: float(psnr(o.clamp(0, 1), reference)[0]) for n, o in outputs.items() if "int8" in n
        },
        "setup_seconds": setup,
        "notes": notes,
        "load_average": [round(value, 2) for value in os.getloadavg()],
    }


def _table(record: dict[str, Any]) -> str:
    lines = [
        f"int8, GEA mono {WIDTH}x{HEIGHT}, batch 1, {record['threads']} threads, "
        f"{record['runs']} runs (median), {record['cpu_model']}; "
        f"{record['network']}, on {record['test_frame']}",
        "",
        "| configuration | median ms | speed vs fp32 | PSNR vs fp32 (dB) | setup s |",
        "|---|---:|---:|---:|---:|",
    ]
    for name, value in record["medians_ms"].items():
        quality = record["psnr_vs_fp32_db"].get(name)
        setup = record["setup_seconds"].get(name)
        lines.append(
            f"| {name} | {value:.1f} | {record['speed_vs_fp32'][name]:.2f}x | "
            f"{'reference' if quality is None else f'{quality:.1f}'} | "
            f"{'' if setup is None else f'{setup:.0f}'} |"
        )
    for name, note in record["notes"].items():
        lines.append(f"\n- {name} skipped: {note}")
    lines.append(f"\n- {record['precision']['reason']}; load average {record['load_average']}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark; print a Markdown table, write ``int8.json`` with ``--out``."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks.bench_int8", description=__doc__)
    parser.add_argument("--out", type=Path, default=None, help="folder for int8.json")
    parser.add_argument(
        "--runs", type=positive_int, default=10, help="timed runs per configuration"
    )
    parser.add_argument("--calibration", type=int, default=8, help="calibration images")
    parser.add_argument("--no-pt2e", action="store_true", help="skip PT2E (slow compile)")
    args = parser.parse_args(argv)
    record = run(args.runs, args.calibration, pt2e=not args.no_pt2e)
    print(_table(record))
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "int8.json").write_text(json.dumps(record, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Benchmark of the anomaly renderer: cost of each effect per 720x540 frame.

    .venv/bin/python -m benchmarks.bench_effects [--out DIR] [--runs 30]

Times :func:`lenspair.simulate.render.render_effects` (sample the glass + render it,
what training does on arbitrary clean images) and
:func:`lenspair.simulate.render.apply_glass` alone (what a recording pays per frame,
the glass being sampled once) on a textured 720x540 scene, mono 8-bit and
RGB 8-bit, for each effect alone, the paper's rain (50 drops + defocus +
brightness), everything at once, and no effect at all. The floor is
``image.copy()``, which any renderer returning a new image must pay.
Medians of ``--runs`` runs with a different seed each; the Markdown table
goes to stdout and, with ``--out``, to ``effects.md`` beside
``effects.json``. Targets: rain frame < 50 ms, no-effect frame < 10 ms.
"""

import argparse
import json
import os
import platform
import statistics
import time
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from lenspair.commands.argtypes import positive_int
from lenspair.simulate.effects.spec import (
    SHARP_DROPS,
    BrightnessSpec,
    DefocusSpec,
    DirtSpec,
    DustSpec,
    EffectsSpec,
    RaindropsSpec,
)
from lenspair.simulate.render import apply_glass, render_effects, sample_glass

HEIGHT, WIDTH = 540, 720
RAIN = EffectsSpec(
    raindrops=RaindropsSpec(count=50), defocus=DefocusSpec(), brightness=BrightnessSpec()
)
CASES: dict[str, EffectsSpec] = {
    "none": EffectsSpec(),
    "raindrops (50, sharp)": SHARP_DROPS,
    "raindrops + brightness": EffectsSpec(raindrops=RaindropsSpec(), brightness=BrightnessSpec()),
    "raindrops + defocus": EffectsSpec(raindrops=RaindropsSpec(), defocus=DefocusSpec()),
    "rain (drops + defocus + brightness)": RAIN,
    "rain + disk blur 3 px": EffectsSpec(
        raindrops=RaindropsSpec(),
        defocus=DefocusSpec(disk_radius_px=3.0),
        brightness=BrightnessSpec(),
    ),
    "dust": EffectsSpec(dust=DustSpec()),
    "dirt": EffectsSpec(dirt=DirtSpec()),
    "all five": EffectsSpec(
        raindrops=RaindropsSpec(),
        defocus=DefocusSpec(),
        brightness=BrightnessSpec(),
        dust=DustSpec(),
        dirt=DirtSpec(),
    ),
}
TARGETS_MS = {"rain (drops + defocus + brightness)": 50.0, "none": 10.0}


def scene(channels: int) -> np.ndarray:
    """A deterministic textured 720x540 scene (sky, gradient, checkerboard, noise)."""
    rng = np.random.default_rng(0)
    ys, xs = np.mgrid[0:HEIGHT, 0:WIDTH]
    image = np.zeros((HEIGHT, WIDTH, 3), np.float32)
    image[..., 0] = xs / WIDTH
    image[..., 1] = ys / HEIGHT
    image[..., 2] = 0.5
    image[ys < HEIGHT // 3] = (0.9, 0.8, 0.6)
    image[((xs // 40 + ys // 40) % 2 == 0) & (ys > HEIGHT // 2)] *= 0.2
    noise = cv2.GaussianBlur(rng.random((HEIGHT, WIDTH), dtype=np.float32), (0, 0), 2.0)
    image = np.clip(image * (0.7 + 0.6 * noise[..., None]), 0.0, 1.0)
    encoded = np.rint(image * 255).astype(np.uint8)
    if channels == 1:
        return np.ascontiguousarray(cv2.cvtColor(encoded, cv2.COLOR_RGB2GRAY))
    return encoded


def median_ms(function: Callable[[int], object], runs: int) -> float:
    """Median wall time of ``function(run_index)`` in milliseconds, after one warm-up."""
    function(-1)
    times = []
    for index in range(runs):
        start = time.perf_counter()
        function(index)
        times.append(time.perf_counter() - start)
    return 1e3 * statistics.median(times)


def run(runs: int) -> dict[str, object]:
    """Time every case on mono and RGB frames; returns the JSON-able result."""
    rows: dict[str, dict[str, float]] = {}
    for channels, label in ((1, "mono8"), (3, "rgb8")):
        image = scene(channels)

        def copy(_: int, image: np.ndarray = image) -> None:
            image.copy()

        floor = median_ms(copy, runs)
        rows.setdefault("floor: image.copy()", {})[f"{label}_render_ms"] = floor
        rows["floor: image.copy()"][f"{label}_apply_ms"] = floor
        for name, spec in CASES.items():

            def render(index: int, spec: EffectsSpec = spec, image: np.ndarray = image) -> None:
                render_effects(image, spec, np.random.default_rng(1000 + index))

            glass = sample_glass(spec, (HEIGHT, WIDTH), np.random.default_rng(7))

            def apply(_: int, glass: object = glass, image: np.ndarray = image) -> None:
                apply_glass(image, glass)  # type: ignore[arg-type]

            row = rows.setdefault(name, {})
            row[f"{label}_render_ms"] = median_ms(render, runs)
            row[f"{label}_apply_ms"] = median_ms(apply, runs)
    checks = {
        name: {
            "target_ms": target,
            "worst_render_ms": max(rows[name]["mono8_render_ms"], rows[name]["rgb8_render_ms"]),
        }
        for name, target in TARGETS_MS.items()
    }
    for check in checks.values():
        check["met"] = check["worst_render_ms"] < check["target_ms"]
    return {
        "frame": f"{WIDTH}x{HEIGHT}",
        "runs": runs,
        "cpu_count": os.cpu_count(),
        "opencv_threads": cv2.getNumThreads(),
        "machine": platform.platform(),
        "load_average_1min": os.getloadavg()[0],
        "python": platform.python_version(),
        "rows": rows,
        "targets": checks,
    }


def markdown(result: dict[str, object]) -> str:
    """The result as a Markdown table (milliseconds per frame, medians)."""
    rows: dict[str, dict[str, float]] = result["rows"]  # type: ignore[assignment]
    lines = [
        f"anomaly renderer, {result['frame']} frames, median of {result['runs']} runs, "
        f"{result['cpu_count']} CPU(s), OpenCV threads {result['opencv_threads']}, "
        f"load average {float(result['load_average_1min']):.1f}",  # type: ignore[arg-type]
        "",
        "render = sample the glass + render it (training); apply = render a sampled glass "
        "(per frame of a recording)",
        "",
        "| effects | mono8 render ms | mono8 apply ms | rgb8 render ms | rgb8 apply ms |",
        "|---|---:|---:|---:|---:|",
    ]
    for name, row in rows.items():
        cells = [row[f"{c}_{k}_ms"] for c in ("mono8", "rgb8") for k in ("render", "apply")]
        lines.append(f"| {name} | " + " | ".join(f"{v:.2f}" for v in cells) + " |")
    lines.append("")
    targets: dict[str, dict[str, object]] = result["targets"]  # type: ignore[assignment]
    for name, check in targets.items():
        verdict = "met" if check["met"] else "MISSED"
        lines.append(
            f"- target {name}: < {check['target_ms']} ms, worst render "
            f"{float(check['worst_render_ms']):.2f} ms ({verdict})"  # type: ignore[arg-type]
        )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    """Command line: run, print the table, write it and the JSON to ``--out``."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--out", type=Path, help="folder for effects.md and effects.json")
    parser.add_argument("--runs", type=positive_int, default=30)
    args = parser.parse_args(argv)
    result = run(args.runs)
    table = markdown(result)
    print(table)
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "effects.md").write_text(table)
        (args.out / "effects.json").write_text(json.dumps(result, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Benchmark of ``dataset-build``: pairs per second against the file I/O floor.

    .venv/bin/python -m benchmarks.bench_dataset [--out DIR] [--pairs 200] [--runs 3]

Writes synthetic ingested recordings (540x360 RGB, both ground-truth sides)
into a temporary folder, then times, in the same run:

* ``build``: :func:`lenspair.dataset.build.build_dataset` end to end (read, hash,
  decode, measure, curate, split, link, manifest, card, contact sheets), each
  round with an empty measurement cache (:mod:`lenspair.dataset.stats_cache`);
* ``rebuild``: the same build again with the figures cached, as a rerun after
  a kill or with other thresholds is: it reads and hashes, but decodes nothing;
* ``io floor``: reading and hashing every image and hard-linking it into a
  fresh folder, which any build must do;
* ``decode floor``: the I/O floor plus decoding every image (PNG inflate),
  which a build that measures pixels must also do.

Medians of ``--runs`` interleaved rounds; ratios are medians of the per-round
ratios of build (and rebuild) time over floor time. The
Markdown table goes to stdout and, with ``--out``, to ``dataset.md``
beside ``dataset.json``.
"""

import argparse
import contextlib
import json
import os
import platform
import shutil
import statistics
import tempfile
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import cv2
import numpy as np

from lenspair.capture.ingested import IngestReport, PairRecord, write_pairs, write_report
from lenspair.commands.argtypes import positive_int
from lenspair.core.fsutil import sha256_bytes, sha256_file
from lenspair.core.imageio import read_image
from lenspair.core.imagewrite import write_image
from lenspair.dataset.build import build_dataset
from lenspair.dataset.config import DatasetConfig, SplitConfig
from lenspair.dataset.stats_cache import CACHE_ENV

HEIGHT, WIDTH = 360, 540


def write_recordings(root: Path, pairs: int, recordings: int = 4) -> list[Path]:
    """Synthetic ingested recordings with ``pairs`` pairs in all; returns their folders."""
    folders = []
    per = -(-pairs // recordings)
    for r in range(recordings):
        rng = np.random.default_rng(r)
        coarse = rng.random((HEIGHT // 8, WIDTH // 2, 3)).astype(np.float32)
        world = cv2.resize(coarse, (WIDTH * 4, HEIGHT), interpolation=cv2.INTER_CUBIC)
        discs = np.zeros((HEIGHT, WIDTH), np.float32)
        for _ in range(12):
            center = (int(rng.integers(20, WIDTH - 20)), int(rng.integers(20, HEIGHT - 20)))
            cv2.circle(discs, center, int(rng.integers(8, 30)), 1.0, -1)
        weight = cv2.GaussianBlur(discs, (0, 0), 3.0)[:, :, None]
        rid = f"bench_{r}"
        folder = root / rid
        records = []
        for i in range(min(per, pairs - r * per)):
            t_ns = 1_700_000_000_000_000_000 + i * 50_000_000
            view = world[:, i * 6 : i * 6 + WIDTH]
            noisy = np.clip(view + rng.normal(0, 0.01, view.shape).astype(np.float32), 0, 1)
            blurred = cv2.GaussianBlur(noisy, (0, 0), 3.0)
            obstructed = noisy * (1 - weight) + blurred * 0.6 * weight
            files = {"input": f"input/{t_ns}.png", "target": f"target/{t_ns}.png"}
            write_image(folder / files["input"], np.rint(obstructed * 255).astype(np.uint8))
            write_image(folder / files["target"], np.rint(noisy * 255).astype(np.uint8))
            sums = {k: sha256_file(folder / v) for k, v in files.items()}
            records.append(PairRecord(t_ns, "kept", residual_px=0.5, files=files, sha256=sums))
        write_pairs(folder / "pairs.jsonl", records)
        write_report(
            folder / "report.json",
            IngestReport(
                recording_id=rid,
                source="synthetic",
                obstructed="cam1" if r % 2 else "cam0",
                anomaly=("rain",),
                calibration_source="synthetic",
                calibration={},
                homography=[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
                crop=(0, 0, WIDTH, HEIGHT),
                counts={"kept": len(records)},
            ),
        )
        folders.append(folder)
    return folders


def _images(folders: list[Path]) -> list[Path]:
    return sorted(p for f in folders for kind in ("input", "target") for p in (f / kind).glob("*"))


def io_floor(images: list[Path], out: Path, decode: bool, workers: int = 1) -> None:
    """Read and hash every image (and decode it when asked), hard-link it into ``out``.

    In ``workers`` threads, as many as the build measures its pairs in
    (``dataset.build._measure``): one thread was no floor for a build on two.
    """
    out.mkdir()

    def one(item: tuple[int, Path]) -> None:
        number, image = item
        sha256_bytes(image.read_bytes())
        if decode:
            read_image(image)
        os.link(image, out / f"{number}.png")

    with ThreadPoolExecutor(max_workers=workers) as pool:
        list(pool.map(one, enumerate(images)))


def _once(action: Callable[[Path], object], target: Path, cache: str = "") -> float:
    """Seconds of ``action(target)`` with the measurement cache in ``cache`` ("": none)."""
    os.environ[CACHE_ENV] = cache
    start = time.perf_counter()
    action(target)
    seconds = time.perf_counter() - start
    shutil.rmtree(target)
    return seconds


def run(pairs: int = 200, runs: int = 3, workers: int | None = None) -> dict[str, object]:
    """Run the benchmark; returns the figures (seconds, pairs per second, ratios).

    The three measurements are interleaved round by round, and the ratios are
    medians of per-round ratios, so that load from other processes hits all
    three alike.
    """
    times: dict[str, list[float]] = {"build": [], "rebuild": [], "io_floor": [], "decode_floor": []}
    cache_before = os.environ.get(CACHE_ENV)
    with tempfile.TemporaryDirectory(prefix="bench_dataset_") as tmp, _restored(cache_before):
        root = Path(tmp)
        folders = write_recordings(root / "ingested", pairs)
        images = _images(folders)
        config = DatasetConfig(split=SplitConfig(segment_frames=10, segment_gap_frames=1))
        threads = workers or min(4, os.cpu_count() or 1)  # the build's own default

        def build(out: Path) -> object:
            return build_dataset(folders, out, config, workers=workers)

        actions: dict[str, Callable[[Path], object]] = {
            "build": build,
            "rebuild": build,
            "io_floor": lambda p: io_floor(images, p, decode=False, workers=threads),
            "decode_floor": lambda p: io_floor(images, p, decode=True, workers=threads),
        }
        warm = str(root / "cache_warm")
        _once(build, root / "warmup", warm)  # the page cache, imports and the rebuilds' cache
        for number in range(runs):
            for name, action in actions.items():
                # a cold build gets a cache of its own, which it fills as a first build does
                cache = {"build": str(root / f"cache_{number}"), "rebuild": warm}.get(name, "")
                times[name].append(_once(action, root / f"{name}_{number}", cache))
    result: dict[str, object] = {
        "pairs": pairs,
        "image_size": [WIDTH, HEIGHT],
        "runs": runs,
        "workers": workers or min(4, os.cpu_count() or 1),
        "cpu_count": os.cpu_count(),
        "load_average": list(os.getloadavg()),
        "machine": platform.machine(),
    }
    for name, values in times.items():
        result[f"{name}_s"] = statistics.median(values)
        result[f"{name}_pairs_per_s"] = pairs / statistics.median(values)
    for built, floor in (("build", "io_floor"), ("build", "decode_floor"), ("rebuild", "io_floor")):
        ratios = [b / f for b, f in zip(times[built], times[floor], strict=True)]
        result[f"{built}_over_{floor}"] = statistics.median(ratios)
    return result


@contextlib.contextmanager
def _restored(value: str | None) -> Iterator[None]:
    """Put :data:`CACHE_ENV` back as it was (``value``; None: unset) afterwards."""
    try:
        yield
    finally:
        if value is None:
            os.environ.pop(CACHE_ENV, None)
        else:
            os.environ[CACHE_ENV] = value


def markdown(result: dict[str, object]) -> str:
    """The figures as a Markdown table."""
    pairs = result["pairs"]
    lines = [
        f"dataset-build, {pairs} pairs of 540x360 RGB PNG, median of {result['runs']} runs, "
        f"{result['workers']} worker thread(s) on {result['cpu_count']} CPU(s), "
        f"load average {result['load_average'][0]:.1f}",  # type: ignore[index]
        "",
        "| what | seconds | pairs/s | build / this |",
        "|---|---:|---:|---:|",
    ]
    for label, key, ratio in (
        ("build (end to end)", "build", None),
        ("rebuild, figures cached (rerun / other thresholds)", "rebuild", None),
        ("I/O floor (read + sha256 + link)", "io_floor", "build_over_io_floor"),
        ("decode floor (I/O floor + PNG decode)", "decode_floor", "build_over_decode_floor"),
    ):
        seconds = float(result[f"{key}_s"])  # type: ignore[arg-type]
        speed = float(result[f"{key}_pairs_per_s"])  # type: ignore[arg-type]
        shown = f"{float(result[ratio]):.2f}x" if ratio else ""  # type: ignore[arg-type]
        lines.append(f"| {label} | {seconds:.3f} | {speed:.1f} | {shown} |")
    rebuild = float(result["rebuild_over_io_floor"])  # type: ignore[arg-type]
    lines += ["", f"rebuild / I/O floor: {rebuild:.2f}x"]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    """Command line: run, print the table, write it and the JSON to ``--out``."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--out", type=Path, help="folder for dataset.md and dataset.json")
    parser.add_argument("--pairs", type=positive_int, default=200)
    parser.add_argument("--runs", type=positive_int, default=3)
    parser.add_argument("--workers", type=int, default=None)
    args = parser.parse_args(argv)
    os.environ.setdefault("LENSPAIR_QUIET", "1")
    result = run(args.pairs, args.runs, args.workers)
    table = markdown(result)
    print(table)
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "dataset.md").write_text(table)
        (args.out / "dataset.json").write_text(json.dumps(result, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

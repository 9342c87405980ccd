"""Benchmark of loading a bag's frames in order: does the cost per pair stay flat as bags grow?

    .venv/bin/python -m benchmarks.bench_bag_read [--out DIR] [--pairs 1000] [--runs 3]

For each kind of bag (ROS 1, ROS 2 db3, ROS 2 MCAP), writes a stereo bag of
``--pairs`` pairs and one four times longer (8x8 mono frames, so that finding a
message, not decoding it, is what is timed), lists it as ``capture-ingest``
does (:func:`lenspair.capture.rosbag.read_bag`) and loads every pair in order
through :func:`lenspair.capture.rosbag.load_bag_frame`, the way ingest's
workers read frames, and again with a query per frame (the cursor's reach
:data:`~lenspair.capture.bag_cursor.AHEAD` set to 0), as lenspair read bags
before it had cursors. ``growth`` is the cost per pair of the long bag over
that of the short one, in the same round: 1 when loading a bag is linear in
its length, 4 when it is quadratic (what rosbags' ROS 1 and MCAP readers cost
when each frame is a query from the bag's start; see
:mod:`lenspair.capture.bag_cursor`). Medians of ``--runs`` rounds; the Markdown
table goes to stdout and, with ``--out``, to ``bag_read.md`` beside
``bag_read.json``.
"""

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from lenspair.capture import bag_cursor
from lenspair.capture.rosbag import close_bag_readers, load_bag_frame, read_bag
from lenspair.commands.argtypes import positive_int
from tests.model.restore_helpers import write_bag

KINDS = ("ros1", "db3", "mcap")
LONGER = 4
"""How many times longer the long bag is."""


def _bag(folder: Path, kind: str, pairs: int) -> Path:
    image = np.zeros((8, 8), np.uint8)
    frames = [(10**18 + i * 50_000_000, image) for i in range(pairs)]
    return Path(write_bag(folder / f"{kind}_{pairs}", kind, {"cam0": frames, "cam1": frames}))


def _per_pair_s(bag: Path, ahead: int) -> float:
    """Seconds per pair to load every pair of ``bag`` in order, from freshly opened readers.

    ``ahead``: how far a cursor reads on (0: a query per frame).
    """
    recording = read_bag(bag)
    close_bag_readers()
    reach, bag_cursor.AHEAD = bag_cursor.AHEAD, ahead
    try:
        start = time.perf_counter()
        for left, right in zip(recording.frames["cam0"], recording.frames["cam1"], strict=True):
            load_bag_frame(left)
            load_bag_frame(right)
        elapsed = time.perf_counter() - start
    finally:
        bag_cursor.AHEAD = reach
        close_bag_readers()
    return elapsed / len(recording.frames["cam0"])


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark; returns 0."""
    parser = argparse.ArgumentParser(
        prog="python -m benchmarks.bench_bag_read", description=__doc__
    )
    parser.add_argument("--out", type=Path, default=None, help="folder for JSON and Markdown")
    parser.add_argument(
        "--pairs", type=positive_int, default=1000, help="pairs of the short bag (default 1000)"
    )
    parser.add_argument("--runs", type=positive_int, default=3, help="timed rounds (default 3)")
    args = parser.parse_args(argv)
    rows: list[dict[str, object]] = []
    with tempfile.TemporaryDirectory(prefix="bench_bag_read_") as tmp:
        root = Path(tmp)
        for kind in KINDS:
            bags = (_bag(root, kind, args.pairs), _bag(root, kind, LONGER * args.pairs))
            row: dict[str, object] = {"kind": kind}
            for name, ahead in (("cursor", bag_cursor.AHEAD), ("query_per_frame", 0)):
                shorts, longs, growths = [], [], []
                for _ in range(args.runs):
                    short_s, long_s = (_per_pair_s(bag, ahead) for bag in bags)
                    shorts.append(short_s)
                    longs.append(long_s)
                    growths.append(long_s / short_s)
                row[f"{name}_short_ms_per_pair"] = 1000 * statistics.median(shorts)
                row[f"{name}_long_ms_per_pair"] = 1000 * statistics.median(longs)
                row[f"{name}_growth"] = statistics.median(growths)
            rows.append(row)
    result = {
        "benchmark": "bag_read",
        "pairs": args.pairs,
        "longer": LONGER,
        "runs": args.runs,
        "rows": rows,
    }
    long = LONGER * args.pairs
    lines = [
        f"Loading every pair of a bag in order: {args.pairs} pairs against {long}, "
        f"8x8 mono frames, medians of {args.runs} rounds",
        "",
        f"| bag | ms per pair, {args.pairs} | ms per pair, {long} | growth | "
        f"a query per frame: ms per pair, {long} | growth |",
        "|---|---:|---:|---:|---:|---:|",
        *(
            f"| {row['kind']} | {row['cursor_short_ms_per_pair']:.3f} | "
            f"{row['cursor_long_ms_per_pair']:.3f} | {row['cursor_growth']:.2f} | "
            f"{row['query_per_frame_long_ms_per_pair']:.3f} | "
            f"{row['query_per_frame_growth']:.2f} |"
            for row in rows
        ),
        "",
        f"growth: ms per pair at {long} over ms per pair at {args.pairs}, in one round "
        f"(1: linear in the bag's length; {LONGER}: quadratic).",
    ]
    table = "\n".join(lines)
    print(table)
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "bag_read.json").write_text(json.dumps(result, indent=2) + "\n")
        (args.out / "bag_read.md").write_text(table + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

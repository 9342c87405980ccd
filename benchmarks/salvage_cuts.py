"""Frames lost by cutting compressed bags short: ``python -m benchmarks.salvage_cuts``.

Writes ROS 1 (bz2, lz4; 768 KiB chunks) and MCAP (zstd; 1 MiB chunks) bags
of 16 random 1536 x 50 rgb8 images (230 KB each, incompressible), cuts each
every ``--step`` bytes and counts, per cut, the frames that ended before it
(chunk data start + decoded end: the images are stored raw, so this is their
compressed end up to block headers) but were not kept; and, for comparison,
how many the old rule (a cut compressed chunk is lost whole) would lose.
The numbers are in README.md's Limitations.
"""

import argparse
import shutil
import statistics
import sys
import tempfile
from pathlib import Path

from lenspair.capture.errors import CaptureError
from lenspair.capture.salvage import salvage_bag
from tests.capture.salvage_helpers import bag_messages, chunk_layout, write_bag

CASES = (("ros1", "lz4"), ("ros1", "bz2"), ("mcap", "zstd"))


def _kept(bag: Path) -> int:
    try:
        salvaged = salvage_bag(bag)
    except CaptureError:  # nothing complete before the cut
        return 0
    salvaged.close()
    return salvaged.message_count


def measure(kind: str, codec: str, step: int, folder: Path) -> str:
    """One Markdown row: lost frames per cut, now and under the whole-chunk rule."""
    bag, storage = write_bag(folder / "run", kind, codec, rows=1536, chunk=768 * 1024)
    whole = storage.read_bytes()
    chunks = chunk_layout(whole, storage, kind, codec, bag_messages(bag, []))
    ends = [c.datapos + end for c in chunks for end in c.ends.values()]
    lost, lost_whole_chunk = [], []
    for cut in range(64 * 1024, len(whole), step):
        storage.write_bytes(whole[:cut])
        ended = sum(end <= cut for end in ends)
        lost.append(ended - _kept(bag))
        lost_whole_chunk.append(
            ended - sum(len(c.ends) for c in chunks if c.datapos + c.size <= cut)
        )
    return (
        f"| {kind} {codec} | {len(whole) / 1e6:.2f} MB, {len(chunks)} chunks | {len(lost)} "
        f"| {statistics.mean(lost):.2f} / {max(lost)} "
        f"| {statistics.mean(lost_whole_chunk):.2f} / {max(lost_whole_chunk)} |"
    )


def main(argv: list[str] | None = None) -> int:
    """Print the table."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks.salvage_cuts")
    parser.add_argument("--step", type=int, default=32 * 1024, help="bytes between cuts")
    args = parser.parse_args(argv)
    print("| bag | size | cuts | frames lost: mean / max | whole-chunk rule: mean / max |")
    print("|---|---|---|---|---|")
    for kind, codec in CASES:
        folder = Path(tempfile.mkdtemp())
        try:
            print(measure(kind, codec, args.step, folder), flush=True)
        finally:
            shutil.rmtree(folder)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Bags cut inside a compressed chunk keep the messages its codec decodes before the cut.

A streaming decoder returns a cut chunk's data block by block: a compressed
block whose end is past the cut gives nothing, a block stored raw comes out
as far as its bytes go. The bound tested: the messages kept are exactly the
whole chunks' messages plus those of the cut chunk whose decompressed end
lies within what the codec's own streaming decoder returns of the chunk's
bytes before the cut, and that is at most one block short of those bytes
(``BLOCK``: bz2 900 kB, lz4 frame 64 KiB, zstd 128 KiB; the images do not
compress). Messages whose compressed bytes straddle the cut are lost.
"""

import shutil
import struct
import tempfile
from pathlib import Path
from typing import NamedTuple

import lz4.frame
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lenspair.capture.errors import CaptureError
from lenspair.capture.salvage import salvage_bag
from tests.capture.salvage_helpers import (
    DECODERS,
    Chunk,
    assert_one_cut_report,
    bag_messages,
    chunk_layout,
    recovered,
    write_bag,
)

# name: (kind, codec, image rows, ROS1 chunk bytes)
CONFIGS = {
    "ros1-bz2": ("ros1", "bz2", 600, 1_000_000),  # a 1.08 MB chunk: two bz2 blocks, and one
    "ros1-lz4": ("ros1", "lz4", 100, 150_000),  # chunks of 2-3 lz4 blocks
    "mcap-zstd": ("mcap", "zstd", 100, 0),  # one chunk of two zstd blocks
    "mcap-lz4": ("mcap", "lz4", 100, 0),  # rosbags' chunk recompressed as an lz4 frame
}
# The most compressed bytes of one block, and some slack for block and frame headers.
BLOCK = {"bz2": 900_000 * 101 // 100, "lz4": 64 * 1024 + 64, "zstd": 128 * 1024 + 64}


class Whole(NamedTuple):
    """An uncut compressed bag, its messages (log time -> raw) and its chunks."""

    bag: Path
    storage: Path
    written: dict[int, bytes]
    chunks: list[Chunk]


def _recompress_mcap_lz4(storage: Path) -> None:
    """Rewrite an uncompressed MCAP's chunks as lz4 frames (rosbags writes only zstd).

    The summary is dropped (its offsets would be stale): a data end, an empty
    footer and the magic follow the data section.
    """
    data = storage.read_bytes()
    out, pos = bytearray(data[:8]), 8
    while True:
        op, length = struct.unpack_from("<BQ", data, pos)
        if op == 0x0F:
            break
        content = data[pos + 9 : pos + 9 + length]
        if op == 0x06:
            (name_size,) = struct.unpack_from("<L", content, 28)
            assert name_size == 0  # written uncompressed
            records = lz4.frame.compress(content[40:])
            content = content[:28] + struct.pack("<L3sQ", 3, b"lz4", len(records)) + records
        out += struct.pack("<BQ", op, len(content)) + content
        pos += 9 + length
    out += struct.pack("<BQL", 0x0F, 4, 0) + struct.pack("<BQQQL", 0x02, 20, 0, 0, 0) + data[:8]
    storage.write_bytes(bytes(out))


@pytest.fixture(scope="module")
def compressed_bags(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Whole]:
    """One uncut bag per configuration."""
    bags = {}
    for name, (kind, codec, rows, chunk) in CONFIGS.items():
        folder = tmp_path_factory.mktemp(name)
        bag, storage = write_bag(
            folder / "run", kind, "none" if name == "mcap-lz4" else codec, rows, chunk
        )
        written = bag_messages(bag, [])
        if name == "mcap-lz4":
            _recompress_mcap_lz4(storage)
        whole = storage.read_bytes()
        bags[name] = Whole(
            bag, storage, written, chunk_layout(whole, storage, kind, codec, written)
        )
        assert {c.codec for c in bags[name].chunks} == {codec}
    return bags


def _expected(whole: Whole, data: bytes, cut: int) -> set[int]:
    """Log times of the messages the codec can give back before ``cut``."""
    expected: set[int] = set()
    for chunk in whole.chunks:
        if chunk.datapos + chunk.size <= cut:
            expected |= set(chunk.ends)
        elif chunk.datapos < cut:
            decoded = len(DECODERS[chunk.codec]().decompress(data[chunk.datapos : cut]))
            assert decoded >= cut - chunk.datapos - BLOCK[chunk.codec]
            expected |= {t for t, end in chunk.ends.items() if end <= decoded}
    return expected


def _cut_copy(whole: Whole, folder: Path, cut: int) -> tuple[Path, Path]:
    copy = folder / whole.bag.name
    if whole.bag.is_dir():
        shutil.copytree(whole.bag, copy)
    storage = copy / whole.storage.name if whole.bag.is_dir() else copy
    storage.write_bytes(whole.storage.read_bytes()[:cut])
    return copy, storage


@pytest.mark.parametrize("name", CONFIGS)
@settings(max_examples=25, deadline=None)
@given(data=st.data())
def test_any_cut_keeps_the_messages_the_codec_decodes(
    compressed_bags: dict[str, Whole], name: str, data: st.DataObject
) -> None:
    whole = compressed_bags[name]
    file_bytes = whole.storage.read_bytes()
    last = len(file_bytes) - 1
    # Images stored raw: a message's compressed end lies a few header bytes past
    # its chunk's data start plus its decompressed end.
    near = [c.datapos + end for c in whole.chunks for end in c.ends.values()]
    near_end = st.sampled_from(near).flatmap(lambda e: st.integers(e - 64, min(e + 64, last)))
    cut = data.draw(st.one_of(st.integers(1, last), near_end), label="cut")
    expected = _expected(whole, file_bytes, cut)
    problems: list[str] = []
    with tempfile.TemporaryDirectory() as folder:
        copy, storage = _cut_copy(whole, Path(folder), cut)
        if not expected:
            with pytest.raises(CaptureError, match="nothing to keep"):
                bag_messages(copy, problems)
            return
        read = bag_messages(copy, problems)
    assert set(read) == expected
    assert sorted(read) == sorted(whole.written)[: len(read)]  # a prefix of the bag
    assert all(raw == whole.written[t] for t, raw in read.items())
    (line,) = problems
    assert f"{storage}: cut short ({cut} bytes): kept the {len(expected)} complete" in line


@pytest.mark.parametrize("name", CONFIGS)
def test_cut_inside_a_compressed_chunk_keeps_its_decoded_frames(
    compressed_bags: dict[str, Whole], name: str, tmp_path: Path
) -> None:
    whole = compressed_bags[name]
    chunk = whole.chunks[0]
    cut = chunk.datapos + chunk.size * 9 // 10  # past the first block of the first chunk
    _, codec, rows, _ = CONFIGS[name]
    copy, storage = _cut_copy(whole, tmp_path, cut)
    found, problems = recovered(copy, rows)
    assert 2 <= len(found) < len(chunk.ends)  # frames of the cut chunk, not all of them
    assert found == list(range(len(found)))
    assert len(found) == len(_expected(whole, whole.storage.read_bytes(), cut))
    assert_one_cut_report(copy, storage, problems)
    assert f"the {codec} chunk record at byte" in problems[0].reason


@pytest.mark.parametrize("name", ["mcap-zstd", "mcap-lz4"])
def test_mcap_cut_inside_a_chunk_header_is_a_cut_not_damage(
    compressed_bags: dict[str, Whole], name: str, tmp_path: Path
) -> None:
    # The header holds times, sizes, the codec's name and the records' length.
    whole = compressed_bags[name]
    chunk = whole.chunks[0]
    record = chunk.datapos - 9 - 40 - len(chunk.codec)
    for cut in range(record + 1, chunk.datapos + 1):
        storage = tmp_path / whole.storage.name
        storage.write_bytes(whole.storage.read_bytes()[:cut])
        with pytest.raises(CaptureError, match="no complete message") as error:
            salvage_bag(storage)
        assert f"record at byte {record} is incomplete" in str(error.value)

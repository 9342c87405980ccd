"""Bags cut short: every complete frame before the cut is read, the cut is reported once."""

import shutil
import sqlite3
import tempfile
from contextlib import closing
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import lenspair.capture.salvage as salvage
from lenspair.capture.errors import CaptureError
from lenspair.capture.frames import iter_frames
from lenspair.capture.recording import open_recording
from tests.capture.salvage_helpers import (
    COUNT,
    MS,
    T0,
    assert_one_cut_report,
    bag_messages,
    pixels,
    recovered,
    write_bag,
)

KINDS = ("ros1", "db3", "mcap")
# Cut points as fractions of the file, drawn once with a fixed seed.
CUTS = sorted(np.random.default_rng(157).uniform(0.2, 0.995, 6).round(3).tolist())


def _assert_recovers(bag: Path, storage: Path, expected: list[int]) -> None:
    """The cut ``bag`` gives exactly the frames ``expected``, and says so once."""
    if len({i % 2 for i in expected}) < 2:  # a camera's first frame is after the cut
        with pytest.raises(CaptureError, match=r"need two image topics.*cut short"):
            open_recording(bag)
        return
    found, problems = recovered(bag)
    assert found == expected
    assert_one_cut_report(bag, storage, problems)
    assert f"kept the {len(expected)} complete messages" in problems[0].reason


@pytest.mark.parametrize("kind", ["ros1", "mcap"])
@pytest.mark.parametrize("cut", CUTS)
def test_cut_bag_keeps_exactly_the_complete_frames(tmp_path: Path, kind: str, cut: float) -> None:
    bag, storage = write_bag(tmp_path / "run", kind)
    data = storage.read_bytes()
    size = int(len(data) * cut)
    # Uncompressed, each image's bytes end its message: complete iff they end before the cut.
    ends = [data.find(pixels(i).tobytes()) + pixels(i).nbytes for i in range(COUNT)]
    expected = [i for i in range(COUNT) if ends[i] <= size]
    storage.write_bytes(data[:size])
    _assert_recovers(bag, storage, expected)


@pytest.mark.parametrize("cut", CUTS)
def test_cut_db3_keeps_exactly_the_rows_before_the_cut(tmp_path: Path, cut: float) -> None:
    # A row's bytes are its cell in a leaf page and its overflow pages; SQLite
    # writes the leaf after the data and moves rows when the root splits, so
    # the rows are read page by page, not through the B-tree.
    bag, storage = write_bag(tmp_path / "run", "db3")
    data = storage.read_bytes()
    size = int(len(data) * cut)
    expected = sorted((t - T0 - MS) // (20 * MS) for t in _db3_rows_before(storage, data, size))
    storage.write_bytes(data[:size])
    _assert_recovers(bag, storage, expected)


@pytest.mark.parametrize("kind", ["ros1", "db3", "mcap"])
def test_cut_bag_iter_frames_reports_the_cut_once(tmp_path: Path, kind: str) -> None:
    bag, storage = write_bag(tmp_path / "run", kind)
    data = storage.read_bytes()
    storage.write_bytes(data[: len(data) * 2 // 3])
    problems: list[str] = []
    frames = list(iter_frames(bag, problems=problems))
    assert frames and all(f.image is not None for f in frames)
    for frame in frames:
        np.testing.assert_array_equal(frame.image, pixels(frame.index))
    (line,) = problems
    assert line.startswith(f"{bag}: reading stopped early after {len(frames)} messages (")
    assert f"{storage}: cut short" in line


@pytest.mark.parametrize("kind", ["ros1", "db3", "mcap"])
def test_bag_cut_before_any_frame_is_one_error(tmp_path: Path, kind: str) -> None:
    bag, storage = write_bag(tmp_path / "run", kind)
    storage.write_bytes(storage.read_bytes()[:300])
    with pytest.raises(CaptureError, match=rf"{bag.name}: cannot open bag \(.*nothing to keep"):
        open_recording(bag)


@pytest.mark.parametrize("kind", ["db3", "mcap"])
def test_cut_bare_storage_file_is_read_too(tmp_path: Path, kind: str) -> None:
    _, storage = write_bag(tmp_path / "run", kind)
    bare = storage.rename(tmp_path / storage.name)
    data = bare.read_bytes()
    bare.write_bytes(data[: len(data) * 2 // 3])
    found, problems = recovered(bare)
    assert len(found) >= 2 and found == list(range(len(found)))
    assert_one_cut_report(bare, bare, problems)


# Property: over any cut, the messages read are exactly those whose bytes all
# lie before it, each byte for byte, and the cut is one line naming the file.


@pytest.fixture(scope="module")
def whole_bags(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Path, Path]]:
    """One uncut bag per kind: ``(bag, storage file)``."""
    return {kind: write_bag(tmp_path_factory.mktemp(kind) / "run", kind) for kind in KINDS}


def _db3_rows_before(storage: Path, data: bytes, cut: int) -> set[int]:
    """Log times of the rows whose bytes all lie before ``cut``, asked of SQLite itself.

    The bytes past the cut of the ``messages`` leaf and overflow pages are
    inverted and SQLite reads every row from the whole tree: a row comes back
    unchanged exactly when none of its bytes is past the cut. (Interior pages
    are kept: they index rows, they hold none of their bytes.)
    """
    with closing(sqlite3.connect(storage)) as db:
        page_size = db.execute("PRAGMA page_size").fetchone()[0]
        pages = [
            pageno
            for (pageno,) in db.execute(
                "SELECT pageno FROM dbstat WHERE name = 'messages' AND pagetype != 'internal'"
            )
        ]
        rows = db.execute("SELECT timestamp, data FROM messages").fetchall()
    damaged = bytearray(data)
    for page in pages:
        start = max(cut, (page - 1) * page_size)
        stop = page * page_size
        damaged[start:stop] = bytes(b ^ 0xFF for b in damaged[start:stop])
    copy = storage.with_name("scrambled.db3")
    copy.write_bytes(damaged)
    kept = set()
    with closing(sqlite3.connect(copy)) as db:
        for log_time, raw in rows:
            try:
                got = db.execute("SELECT data FROM messages WHERE timestamp = ?", (log_time,))
                if bytes(got.fetchone()[0]) == raw:
                    kept.add(log_time)
            except sqlite3.DatabaseError:
                continue
    copy.unlink()
    return kept


def _first_leaf_end(storage: Path) -> int:
    """Where the first leaf page of ``messages`` ends; rows before it move there on a split."""
    with closing(sqlite3.connect(storage)) as db:
        page_size = db.execute("PRAGMA page_size").fetchone()[0]
        (first,) = db.execute(
            "SELECT min(pageno) FROM dbstat WHERE name = 'messages' AND pagetype = 'leaf'"
        ).fetchone()
    return int(first) * int(page_size)


@pytest.mark.parametrize("kind", KINDS)
@settings(max_examples=40, deadline=None)
@given(data=st.data())
def test_any_cut_keeps_exactly_the_messages_before_it(
    whole_bags: dict[str, tuple[Path, Path]], kind: str, data: st.DataObject
) -> None:
    bag, storage = whole_bags[kind]
    whole = storage.read_bytes()
    written = bag_messages(bag, [])
    assert len(written) == COUNT
    # Each message's last byte: uncompressed, its raw bytes lie whole in the file.
    ends = [whole.find(raw[-64:]) + 64 for raw in written.values()]
    assert min(ends) >= 64  # found: no tail straddles two db3 pages
    last = len(whole) - 1
    near_end = st.sampled_from(ends).flatmap(lambda end: st.integers(end - 2, min(end + 2, last)))
    cut = data.draw(st.one_of(st.integers(1, last), near_end), label="cut")
    with tempfile.TemporaryDirectory() as folder:
        copy = Path(folder) / bag.name
        if bag.is_dir():
            shutil.copytree(bag, copy)
        cut_storage = copy / storage.name if bag.is_dir() else copy
        cut_storage.write_bytes(whole[:cut])
        if kind == "db3":
            expected = _db3_rows_before(storage, whole, cut)
        else:
            expected = {t for t, raw in written.items() if whole.find(raw) + len(raw) <= cut}
        problems: list[str] = []
        if not expected:
            with pytest.raises(CaptureError, match="nothing to keep"):
                bag_messages(copy, problems)
            return
        read = bag_messages(copy, problems)
    assert set(read) == expected
    assert all(raw == written[t] for t, raw in read.items())
    if kind == "db3" and cut >= _first_leaf_end(storage):
        # Each leaf page is written after the data of the first row it holds:
        # past the first leaf, at most that one row ends before the cut and is lost.
        assert sum(end <= cut for end in ends) - len(read) <= 1
    (line,) = problems
    assert f"{cut_storage}: cut short ({cut} bytes): kept the {len(expected)} complete" in line


def test_cut_db3_skips_the_stale_rows_of_free_pages(tmp_path: Path) -> None:
    # Without secure_delete, a dropped table's leaf pages go to the free list
    # with their cells still in them: stale rows, not messages.
    bag, storage = write_bag(tmp_path / "run", "db3")
    with closing(sqlite3.connect(storage)) as db:
        db.execute("PRAGMA secure_delete = OFF")
        db.execute("CREATE TABLE old (id INTEGER PRIMARY KEY, t INTEGER, ts INTEGER, b BLOB)")
        db.execute("INSERT INTO old SELECT id + 100, topic_id, timestamp + 7, data FROM messages")
        db.commit()
        db.execute("DROP TABLE old")
        db.execute("DELETE FROM messages WHERE id IN (3, 4, 9)")
        db.commit()
    data = storage.read_bytes()
    cut = len(data) * 9 // 10
    expected = _db3_rows_before(storage, data, cut)
    deleted = {T0 + MS + index * 20 * MS for index in (2, 3, 8)}
    assert len(expected) >= 10 and not expected & deleted
    storage.write_bytes(data[:cut])
    assert set(bag_messages(bag, [])) == expected


@pytest.mark.parametrize("kind", ["ros1", "db3", "mcap"])
def test_a_cut_bag_is_scanned_once_until_it_changes(
    tmp_path: Path, kind: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    scans: list[str] = []
    for name in ("scan_ros1", "scan_mcap", "scan_db3"):
        scan = getattr(salvage, name)
        monkeypatch.setattr(salvage, name, lambda *a, _s=scan, _n=name: scans.append(_n) or _s(*a))
    bag, storage = write_bag(tmp_path / "run", kind)
    data = storage.read_bytes()
    storage.write_bytes(data[: len(data) * 2 // 3])
    first, _ = recovered(bag)
    again, _ = recovered(bag)  # lists topics, counts and reads: the scan is reused
    assert again == first and len(scans) == 1
    storage.write_bytes(data[: len(data) // 2])  # the same file, shorter
    fewer, _ = recovered(bag)
    assert len(scans) == 2 and 0 < len(fewer) < len(first)
    cut = bytearray(data[: len(data) // 2])
    cut[-1] ^= 0xFF  # the same size, changed within the file times' clock tick
    storage.write_bytes(bytes(cut))
    recovered(bag)
    assert len(scans) == 3

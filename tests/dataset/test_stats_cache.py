"""The measurement cache of dataset-build: reruns decode nothing twice, and change nothing."""

import logging
import math
import struct
import threading
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from lenspair.dataset import curation, stats_cache
from lenspair.dataset.build import build_dataset
from lenspair.dataset.config import CurationConfig, DatasetConfig
from lenspair.dataset.curation import PairStats
from lenspair.dataset.stats_cache import StatsCache, cache_folder
from tests.dataset.dataset_synth import RecordingFactory


def _files(root: Path) -> dict[str, bytes]:
    return {
        str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()
    }


def _counting(monkeypatch: pytest.MonkeyPatch, fail_after: int | None = None) -> list[int]:
    """Count calls of measure_pair (the decoding is done just before it); optionally fail."""
    calls: list[int] = []
    real = curation.measure_pair

    def measure(*args: object) -> PairStats:
        if fail_after is not None and len(calls) >= fail_after:
            raise KeyboardInterrupt  # as Ctrl-C in the middle of measuring
        calls.append(1)
        return real(*args)  # type: ignore[arg-type]

    monkeypatch.setattr(curation, "measure_pair", measure)
    return calls


def _entries() -> list[Path]:
    folder = cache_folder()
    assert folder is not None
    return sorted(folder.rglob("*.json"))


def test_a_pair_whose_file_changes_while_it_is_measured_is_not_kept(
    recording: RecordingFactory, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # the new pixels' figures were kept under the old bytes' key: a later build that read
    # the old file again took psnr 12.6 dB for a pair of 21.7
    source = recording("rec_a", n=4)
    real = curation.measure_pair
    touched: list[Path] = []

    def measure(*args: object) -> PairStats:
        if not touched:  # a re-ingest rewrites a target between hashing and decoding
            target = sorted((source / "target").iterdir())[0]
            fresh = target.with_suffix(".new")  # as capture-ingest writes: a new file, renamed
            fresh.write_bytes(target.read_bytes())
            fresh.replace(target)
            touched.append(target)
        return real(*args)  # type: ignore[arg-type]

    monkeypatch.setattr(curation, "measure_pair", measure)
    build_dataset([source], tmp_path / "DS1", DatasetConfig(), workers=1)
    assert len(_entries()) == 3
    monkeypatch.undo()
    calls = _counting(monkeypatch)
    build_dataset([source], tmp_path / "DS2", DatasetConfig(), workers=1)
    assert len(calls) == 1


def test_entries_of_other_versions_are_removed_when_a_build_opens_the_cache(
    recording: RecordingFactory, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    source = recording("rec_a", n=3)
    build_dataset([source], tmp_path / "DS", DatasetConfig())
    folder = cache_folder()
    assert folder is not None
    (old,) = folder.iterdir()
    mine = folder / "notes"  # not a version's folder: left alone
    mine.mkdir()
    monkeypatch.setattr(stats_cache, "code_fingerprint", lambda: "0123456789abcdef" * 4)
    build_dataset([source], tmp_path / "DS", DatasetConfig())
    assert sorted(p.name for p in folder.iterdir()) == ["0123456789abcdef", "notes"]
    assert not old.exists() and len(_entries()) == 3


def test_no_home_folder_turns_the_cache_off(monkeypatch: pytest.MonkeyPatch) -> None:
    # Path.home() raised RuntimeError: dataset-build failed in a container without HOME
    for name in ("LENSPAIR_CACHE_DIR", "XDG_CACHE_HOME", "HOME"):
        monkeypatch.delenv(name, raising=False)

    def no_home() -> Path:
        raise RuntimeError("Could not determine home directory.")

    monkeypatch.setattr(Path, "home", staticmethod(no_home))
    assert cache_folder() is None


def test_a_rebuild_reads_every_figure_back_and_writes_the_same_dataset(
    recording: RecordingFactory, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    sources = [
        recording("rec_a", n=12, still=(3,), clean=(7,), rejected=(9,)),
        recording("rec_b", seed=1),
    ]
    first = build_dataset(sources, tmp_path / "DS1", DatasetConfig())
    assert len(_entries()) == 12 + 12 - 1  # every measured pair; the rejected one is not
    calls = _counting(monkeypatch)
    second = build_dataset(sources, tmp_path / "DS2", DatasetConfig())
    assert calls == []
    assert _files(tmp_path / "DS1") == _files(tmp_path / "DS2")
    assert first.rows == second.rows and first.card == second.card


def test_a_build_stopped_while_measuring_measures_only_the_rest_on_a_rerun(
    recording: RecordingFactory, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    source = recording("rec_a", n=12)
    _counting(monkeypatch, fail_after=5)
    with pytest.raises(KeyboardInterrupt):
        build_dataset([source], tmp_path / "DS", DatasetConfig(), workers=1)
    monkeypatch.undo()
    calls = _counting(monkeypatch)
    build_dataset([source], tmp_path / "DS", DatasetConfig(), workers=1)
    assert len(calls) == 12 - 5


def test_other_thresholds_reuse_figures_and_another_anomaly_delta_measures_again(
    recording: RecordingFactory, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    source = recording("rec_a", n=8)
    build_dataset([source], tmp_path / "DS", DatasetConfig())
    calls = _counting(monkeypatch)
    stricter = DatasetConfig(curation=CurationConfig(min_sharpness=40.0, duplicate_threshold=0.01))
    build_dataset([source], tmp_path / "DS", stricter, overwrite=True)
    assert calls == []  # thresholds apply to the figures: nothing to measure
    delta = DatasetConfig(curation=CurationConfig(anomaly_delta=0.2))
    build_dataset([source], tmp_path / "DS", delta, overwrite=True)
    assert len(calls) == 8  # the anomaly fraction depends on it


def test_a_change_of_the_measuring_code_measures_again(
    recording: RecordingFactory, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    source = recording("rec_a", n=6)
    build_dataset([source], tmp_path / "DS", DatasetConfig())
    monkeypatch.setattr(stats_cache, "code_fingerprint", lambda: "edited")
    calls = _counting(monkeypatch)
    build_dataset([source], tmp_path / "DS", DatasetConfig())
    assert len(calls) == 6


def test_the_code_is_fingerprinted_once_before_the_measuring_threads(
    recording: RecordingFactory, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # ast.parse in several threads at once raised "SystemError: AST constructor recursion
    # depth mismatch" (CPython 3.11): the first pairs of a build failed at random
    threads: list[threading.Thread] = []
    monkeypatch.setattr(
        stats_cache, "code_fingerprint", lambda: threads.append(threading.current_thread()) or "c"
    )
    build_dataset([recording("rec_a", n=8)], tmp_path / "DS", DatasetConfig(), workers=4)
    assert threads == [threading.current_thread()]


def test_an_entry_cut_short_is_measured_again_and_rewritten(
    recording: RecordingFactory, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    source = recording("rec_a", n=6)
    build_dataset([source], tmp_path / "DS1", DatasetConfig())
    cut = _entries()[2]
    whole = cut.read_bytes()
    cut.write_bytes(whole[: len(whole) // 2])
    calls = _counting(monkeypatch)
    build_dataset([source], tmp_path / "DS2", DatasetConfig())
    assert len(calls) == 1 and cut.read_bytes() == whole
    assert _files(tmp_path / "DS1") == _files(tmp_path / "DS2")


def test_a_cache_folder_that_cannot_be_written_is_said_once_and_the_build_goes_on(
    recording: RecordingFactory,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    caplog: pytest.LogCaptureFixture,
) -> None:
    source = recording("rec_a", n=6)
    build_dataset([source], tmp_path / "DS1", DatasetConfig())
    blocked = tmp_path / "not_a_folder"
    blocked.write_text("a file where the cache folder would be")  # refused even to root
    monkeypatch.setenv("LENSPAIR_CACHE_DIR", str(blocked))
    with caplog.at_level(logging.WARNING):
        build_dataset([source], tmp_path / "DS2", DatasetConfig())
    said = [r.getMessage() for r in caplog.records if "measurement cache" in r.getMessage()]
    assert len(said) == 1 and str(blocked) in said[0] and "LENSPAIR_CACHE_DIR" in said[0]
    assert _files(tmp_path / "DS1") == _files(tmp_path / "DS2")


def test_where_the_cache_lives(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("LENSPAIR_CACHE_DIR", "")
    assert cache_folder() is None
    monkeypatch.delenv("LENSPAIR_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert cache_folder() == tmp_path / "lenspair" / "pair-stats"
    monkeypatch.delenv("XDG_CACHE_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert cache_folder() == tmp_path / "home" / ".cache" / "lenspair" / "pair-stats"


def test_a_build_with_the_cache_off_writes_none(
    recording: RecordingFactory, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    source = recording("rec_a", n=4)
    monkeypatch.setenv("LENSPAIR_CACHE_DIR", "")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    calls = _counting(monkeypatch)
    build_dataset([source], tmp_path / "DS1", DatasetConfig())
    build_dataset([source], tmp_path / "DS2", DatasetConfig())
    assert len(calls) == 8 and not (tmp_path / "xdg").exists()


def _bits(value: float) -> bytes:
    return struct.pack("<d", value)


figures = st.floats(allow_nan=True, allow_infinity=True, width=64)


@given(
    values=st.tuples(*(figures for _ in range(6))),
    thumbnail=arrays(np.float32, st.tuples(st.integers(0, 5), st.integers(0, 7))),
)
def test_figures_come_back_bit_for_bit(
    values: tuple[float, ...], thumbnail: np.ndarray, tmp_path_factory: pytest.TempPathFactory
) -> None:
    cache = StatsCache(tmp_path_factory.mktemp("c"))
    stats = PairStats(*values, thumbnail=thumbnail)
    cache.put("ab" * 32, stats)
    back = cache.get("ab" * 32)
    assert back is not None and cache.hits == 1
    for name in ("psnr_db", "anomaly_fraction", "sharpness", "saturated", "black", "mask_fraction"):
        original, kept = getattr(stats, name), getattr(back, name)
        assert type(kept) is float
        assert _bits(kept) == _bits(original) or (math.isnan(kept) and math.isnan(original))
    assert back.thumbnail.dtype == np.float32 and back.thumbnail.shape == thumbnail.shape
    assert back.thumbnail.tobytes() == thumbnail.tobytes()


@pytest.mark.parametrize(
    "edit",
    [
        lambda e: e.replace('"black": ', '"black": "0.5", "x": '),  # a figure as text
        lambda e: e.replace('"shape": [24, 32]', '"shape": [24, 31]'),  # a wrong shape
        lambda e: e[:-40],  # cut short
        lambda e: e.replace('"sharpness"', '"sharp"'),  # a figure missing
    ],
)
def test_an_entry_that_does_not_read_as_figures_is_absent(edit: object, tmp_path: Path) -> None:
    cache = StatsCache(tmp_path)
    stats = PairStats(30.0, 0.1, 50.0, 0.0, 0.0, 0.0, np.zeros((24, 32), np.float32))
    cache.put("cd" * 32, stats)
    (entry,) = tmp_path.rglob("*.json")
    entry.write_text(edit(entry.read_text()))  # type: ignore[operator]
    assert cache.get("cd" * 32) is None and cache.hits == 0


def test_the_code_fingerprint_follows_lenspair_imports_only() -> None:
    source = b"""
import os
import lenspair.core.pixels
from lenspair.core import quality, errors as e
from . import curation
def late():
    from lenspair.core.fsutil import sha256_bytes
"""
    found = set(stats_cache._lenspair_imports(source, False, "lenspair.dataset.sources"))
    assert found == {
        "lenspair.core.pixels",
        "lenspair.core",
        "lenspair.core.quality",
        "lenspair.core.errors",
        "lenspair.dataset",
        "lenspair.dataset.curation",
        "lenspair.core.fsutil",
    }
    measured = dict(stats_cache._module_sources(stats_cache.MEASURING_MODULES))
    # what measure_pair and read_image run: a change to any of them gives new keys
    assert {"lenspair.core.pixels", "lenspair.core.quality", "lenspair.core.pngcheck"} <= set(
        measured
    )

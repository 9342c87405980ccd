"""bench_dataset: floors doing the build's work in its threads; builds that measure."""

import os
import threading
from pathlib import Path

import numpy as np
import pytest

from benchmarks import bench_dataset
from lenspair.core.imagewrite import write_image
from lenspair.dataset import curation
from lenspair.dataset.stats_cache import CACHE_ENV


def test_the_floors_link_every_image_in_the_build_s_threads(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # the floors ran on one thread while the build measured its pairs on two: no floor
    images = []
    for number in range(6):
        path = tmp_path / "in" / f"{number}.png"
        write_image(path, np.full((8, 8), number * 40, np.uint8))
        images.append(path)
    threads: set[int] = set()
    real = bench_dataset.read_image

    def decode(path: Path) -> np.ndarray:
        threads.add(threading.get_ident())
        return real(path)

    monkeypatch.setattr(bench_dataset, "read_image", decode)
    bench_dataset.io_floor(images, tmp_path / "out", decode=True, workers=2)
    linked = sorted(p.name for p in (tmp_path / "out").iterdir())
    assert linked == [f"{n}.png" for n in range(6)]
    assert all((tmp_path / "out" / f"{n}.png").samefile(images[n]) for n in range(6))
    assert threads and threading.get_ident() not in threads  # the pool's, not the caller's


def test_each_cold_build_measures_every_pair_and_a_rebuild_none(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # with the measurement cache, every round after the warm-up read the figures back, and
    # "build over decode floor" timed a build that decoded nothing
    monkeypatch.setenv(CACHE_ENV, "/the/user's/cache")
    measured: list[int] = []
    real = curation.measure_pair
    monkeypatch.setattr(curation, "measure_pair", lambda *a: measured.append(1) or real(*a))
    result = bench_dataset.run(pairs=8, runs=2, workers=1)
    assert len(measured) == 8 * (1 + 2)  # the warm-up and each cold build; no rebuild
    assert os.environ[CACHE_ENV] == "/the/user's/cache"
    assert float(result["rebuild_s"]) > 0 and "rebuild_over_io_floor" in result  # type: ignore[arg-type]

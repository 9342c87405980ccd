"""bench_dataset's floors: the same work for every image, in the build's threads."""

import threading
from pathlib import Path

import numpy as np
import pytest

from benchmarks import bench_dataset
from lenspair.core.imagewrite import write_image


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

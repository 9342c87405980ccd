"""Folder recordings for the restore and detect tests: textured frames in EuRoC layout."""

from pathlib import Path

import numpy as np

from lenspair.core.imagewrite import write_image
from tests.images import texture

TIMES = (1_700_000_000_000_000_000, 1_700_000_000_050_000_000)
"""The frames' timestamps (ns): two a camera."""


def textured_image(path: Path, seed: int, shape: tuple[int, int] = (32, 48)) -> None:
    """An 8-bit grey texture of ``shape`` at ``path``."""
    write_image(path, (texture(shape, seed=seed) * 255).astype(np.uint8))


def euroc_recording(
    root: Path,
    cameras: tuple[str, ...] = ("cam0", "cam1", "cam2"),
    shape: tuple[int, int] = (32, 48),
) -> Path:
    """An EuRoC recording of :data:`TIMES` frames a camera (a third camera too, by default)."""
    rows = "".join(f"{t},{t}.png\n" for t in TIMES)
    for seed, camera in enumerate(cameras):
        (root / "mav0" / camera).mkdir(parents=True)
        (root / "mav0" / camera / "data.csv").write_text("#timestamp [ns],filename\n" + rows)
        for index, t_ns in enumerate(TIMES):
            frame = root / "mav0" / camera / "data" / f"{t_ns}.png"
            textured_image(frame, 10 * seed + index, shape)
    return root

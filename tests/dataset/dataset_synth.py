"""Synthetic ingested recordings (the capture-ingest contract) for the dataset tests."""

from collections.abc import Callable, Collection
from pathlib import Path

import cv2
import numpy as np

from lenspair.capture.ingested import IngestReport, PairRecord, write_pairs, write_report
from lenspair.core.fsutil import sha256_file
from lenspair.core.imagewrite import write_image

T0_NS = 1_700_000_000_000_000_000
DT_NS = 50_000_000


def scene(rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    """A wide float32 RGB texture in [0, 1] (coarse blobs plus fine detail)."""
    coarse = cv2.resize(
        rng.random((height // 4 + 2, width // 2 + 2, 3)).astype(np.float32),
        (width * 4, height),
        interpolation=cv2.INTER_CUBIC,
    )
    fine = rng.random((height, width * 4, 3)).astype(np.float32)
    return np.clip(0.15 + 0.55 * coarse + 0.3 * fine, 0.0, 1.0)


def add_drops(target: np.ndarray, strength: float, rng: np.random.Generator) -> np.ndarray:
    """Darken and blur a few disc-shaped regions (fixed glass state from ``rng``)."""
    height, width = target.shape[:2]
    blurred = cv2.GaussianBlur(target, (0, 0), 2.0)
    discs = np.zeros((height, width), np.float32)
    for _ in range(3):
        cx, cy = int(rng.integers(8, width - 8)), int(rng.integers(8, height - 8))
        cv2.circle(discs, (cx, cy), max(4, height // 8), 1.0, -1)
    weight = cv2.GaussianBlur(discs, (0, 0), 1.0)[:, :, None]
    return target * (1 - weight) + blurred * (1 - strength) * weight


def make_recording(
    root: Path,
    rid: str,
    *,
    n: int = 12,
    obstructed: str = "cam1",
    anomaly: tuple[str, ...] = ("rain",),
    size: tuple[int, int] = (48, 64),
    seed: int = 0,
    strength: float = 0.5,
    still: Collection[int] = (),
    blurred: Collection[int] = (),
    clean: Collection[int] = (),
    rejected: Collection[int] = (),
    masked: bool = False,
    dtype: type = np.uint8,
    t0_ns: int = T0_NS,
) -> Path:
    """Write ``root/rid`` as capture-ingest would; returns the folder.

    ``still`` frames repeat the previous view (plus sensor noise), ``blurred``
    frames have a motion-blurred clean view, ``clean`` frames show no anomaly,
    ``rejected`` frames are rejected at ingest. Frames are ``DT_NS`` apart
    from ``t0_ns``.
    """
    rng = np.random.default_rng(seed)
    height, width = size
    world = scene(rng, height, width)
    folder = root / rid
    records = []
    offset = 0
    full = float(np.iinfo(dtype).max)
    for i in range(n):
        t_ns = t0_ns + i * DT_NS
        if i in rejected:
            records.append(PairRecord(t_ns, "rejected", reason="too few matches", inliers=3))
            continue
        if i not in still:
            offset += 5
        view = world[:, offset % (3 * width) : offset % (3 * width) + width]
        target = np.clip(view + rng.normal(0, 0.002, view.shape).astype(np.float32), 0, 1)
        if i in blurred:
            target = cv2.GaussianBlur(target, (0, 0), 4.0)
        glass = np.random.default_rng(seed + 1000)  # same drops on every frame
        obstructed_view = target if i in clean else add_drops(target, strength, glass)
        files = {"input": f"input/{t_ns}.png", "target": f"target/{t_ns}.png"}
        write_image(folder / files["input"], np.rint(obstructed_view * full).astype(dtype))
        write_image(folder / files["target"], np.rint(target * full).astype(dtype))
        if masked:
            mask = np.zeros((height, width), np.uint8)
            mask[:, :4] = 255
            files["mask"] = f"mask/{t_ns}.png"
            write_image(folder / files["mask"], mask)
        records.append(
            PairRecord(
                t_ns,
                "kept",
                t_clean_ns=t_ns + 1_000,
                residual_px=0.4,
                photometric_residual=0.01,
                inliers=120,
                files=files,
                sha256={kind: sha256_file(folder / rel) for kind, rel in files.items()},
            )
        )
    write_pairs(folder / "pairs.jsonl", records)
    kept = sum(1 for r in records if r.status == "kept")
    write_report(
        folder / "report.json",
        IngestReport(
            recording_id=rid,
            source=f"/recordings/{rid}",
            obstructed=obstructed,
            anomaly=anomaly,
            calibration_source=f"/recordings/{rid}/camchain.yaml",
            calibration={},
            homography=[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            crop=(0, 0, width, height),
            counts={"frames_cam0": n, "kept": kept, "rejected": n - kept},
            rejection_reasons={"too few matches": n - kept} if n > kept else {},
            lenspair_version="0.1.0",
        ),
    )
    return folder


RecordingFactory = Callable[..., Path]
"""``factory(rid, **options)`` -> folder of a synthetic ingested recording."""

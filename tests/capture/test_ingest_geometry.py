"""Ingest against simulator truth: dust on the left camera, and a near object (parallax)."""

from pathlib import Path

import numpy as np

from lenspair.capture.ingest import ingest_recording
from lenspair.capture.ingested import read_pairs
from lenspair.core.imageio import read_image
from lenspair.rectify.registration import EstimationParams
from tests.capture.ingest_helpers import plane_region, registration_errors, simulate

FEW_FRAMES = EstimationParams(max_frames=2)


def test_dust_on_the_left_camera(tmp_path: Path) -> None:
    recording = simulate("dust_swapped", tmp_path / "dust_swapped", frames=3)
    report = ingest_recording(recording, tmp_path / "out", estimation=FEW_FRAMES)
    assert report.obstructed == "cam0" and report.counts["kept"] >= 2
    errors = registration_errors(recording, tmp_path / "out" / "dust_swapped")
    median = float(np.median(np.concatenate(list(errors.values()))))
    print(f"dust_swapped: median registration error {median:.4f} px")
    assert median < 0.25


def test_near_object_is_masked(tmp_path: Path) -> None:
    recording = simulate("parallax", tmp_path / "parallax", frames=3)
    ingest_recording(recording, tmp_path / "out", estimation=FEW_FRAMES)
    out_dir = tmp_path / "out" / "parallax"
    records = read_pairs(out_dir / "pairs.jsonl")
    assert records
    errors = registration_errors(recording, out_dir)
    assert float(np.median(np.concatenate(list(errors.values())))) < 0.25  # far plane still fine
    for record in records:
        near = plane_region(recording, out_dir, record.t_ns, "near_board")
        assert near.mean() > 0.03  # the board is in view
        if record.status == "rejected":
            assert record.reason is not None and record.reason.startswith("parallax")
            continue
        mask = read_image(out_dir / record.files["mask"]) > 0
        covered = float(mask[near].mean())
        print(f"parallax {record.t_ns}: mask covers {covered:.1%} of the near board")
        assert covered > 0.95
        # the mask is the board, its shifted copy in the target and a margin; not the frame
        assert float(mask[~near].mean()) < 0.05

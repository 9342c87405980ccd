"""Realism statistics: each pinned on constructed pairs whose answer is known."""

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lenspair.cli import main
from lenspair.core.imagewrite import write_image
from lenspair.simulate import realism
from lenspair.simulate.effects.spec import SHARP_DROPS
from lenspair.simulate.errors import SimulateError
from lenspair.simulate.natural_images import NATURAL_IMAGES, load_natural_images
from lenspair.simulate.realism import (
    REAL_RANGES,
    STATISTIC_NAMES,
    RealismStatistics,
    format_ranges,
    measure_pairs,
    realism_statistics,
    rendered_pairs,
    summarise,
)

TOP = 65535


def _clean(shape: tuple[int, int] = (96, 128), seed: int = 0) -> np.ndarray:
    """A textured uint16 image in the middle of the range (no clipping when offset)."""
    rng = np.random.default_rng(seed)
    values = rng.uniform(0.3, 0.6, shape)
    return np.round(values * TOP).astype(np.uint16)


def test_identical_images_change_nothing() -> None:
    clean = _clean()
    stats = realism_statistics(clean, clean)
    assert stats == RealismStatistics(0.0, 0.0, 0.0, 1.0, math.inf)


@pytest.mark.parametrize("offset_code", [1000, 6554, 13107])
def test_a_uniform_brightening_is_all_low_frequency(offset_code: int) -> None:
    clean = _clean()
    obstructed = clean + np.uint16(offset_code)
    offset = offset_code / TOP
    stats = realism_statistics(obstructed, clean)
    assert stats.mean_difference == pytest.approx(offset, abs=1e-6)
    assert stats.coverage == (1.0 if offset > 0.05 else 0.0)
    assert stats.high_frequency == pytest.approx(0.0, abs=1e-6)
    assert stats.contrast_ratio == pytest.approx(1.0, abs=1e-6)
    assert stats.input_psnr == pytest.approx(20 * math.log10(1 / offset), abs=1e-3)


def test_pixel_checkerboard_difference_is_all_high_frequency_and_invisible() -> None:
    clean = _clean()
    rows, cols = np.indices(clean.shape)
    sign = np.where((rows + cols) % 2 == 0, 1, -1)
    obstructed = (clean.astype(np.int64) + sign * 6554).astype(np.uint16)
    stats = realism_statistics(obstructed, clean)
    assert stats.high_frequency == pytest.approx(1.0, abs=1e-3)
    assert stats.coverage == 0.0  # blurred at sigma 2 it averages out
    assert stats.mean_difference == pytest.approx(0.0, abs=1e-6)


def test_half_frame_step_covers_half_plus_the_blur_margin() -> None:
    height, width, step = 64, 200, 0.2
    clean = _clean((height, width))
    obstructed = clean.copy()
    obstructed[:, : width // 2] += np.uint16(round(step * TOP))
    # The blurred step at distance x (pixels) past the edge is step * Phi(-x / sigma):
    # the first column beyond the edge (x = 0.5) is above 0.05, the second (1.5) is not.
    phi = [0.5 * (1 + math.erf(-(x / 2.0) / math.sqrt(2))) for x in (0.5, 1.5)]
    assert step * phi[0] > 0.05 > step * phi[1]
    stats = realism_statistics(obstructed, clean)
    assert stats.coverage == pytest.approx((width // 2 + 1) / width)
    assert stats.mean_difference == pytest.approx(step / 2, abs=1e-4)


@given(gain=st.floats(0.2, 1.0))
@settings(max_examples=20, deadline=None)
def test_contrast_ratio_of_a_scaled_image_is_the_scale(gain: float) -> None:
    clean = _clean()
    values = clean / TOP
    obstructed = np.round((0.45 + gain * (values - 0.45)) * TOP).astype(np.uint16)
    stats = realism_statistics(obstructed, clean)
    assert stats.contrast_ratio == pytest.approx(gain, abs=2e-4)


def test_smooth_difference_has_little_high_frequency() -> None:
    clean = _clean((120, 160))
    rows, cols = np.indices(clean.shape)
    bump = 0.1 * np.exp(-((rows - 60) ** 2 + (cols - 80) ** 2) / (2 * 30.0**2))
    obstructed = np.round(clean + bump * TOP).astype(np.uint16)
    stats = realism_statistics(obstructed, clean)
    assert stats.high_frequency < 0.01
    mse = float(np.mean((obstructed / TOP - clean / TOP) ** 2))
    assert stats.input_psnr == pytest.approx(10 * math.log10(1 / mse), abs=1e-3)


def test_rgb_is_measured_on_its_luma() -> None:
    clean_grey = _clean()
    obstructed_grey = clean_grey + np.uint16(3000)
    rgb = (np.repeat(clean_grey[..., None], 3, 2), np.repeat(obstructed_grey[..., None], 3, 2))
    grey_stats = realism_statistics(obstructed_grey, clean_grey)
    rgb_stats = realism_statistics(rgb[1], rgb[0])
    for name in STATISTIC_NAMES:
        assert getattr(rgb_stats, name) == pytest.approx(getattr(grey_stats, name), abs=1e-4)


def test_bad_pairs_raise_and_are_recorded_not_fatal() -> None:
    clean = _clean()
    with pytest.raises(SimulateError, match="differ in size"):
        realism_statistics(clean[:10], clean)
    flat = np.full((8, 8), 100, np.uint8)
    with pytest.raises(SimulateError, match="flat"):
        realism_statistics(flat, flat)
    results = measure_pairs([("flat", flat, flat, None), ("good", clean, clean, None)])
    assert results[0].statistics is None and "flat" in str(results[0].problem)
    assert results[1].statistics is not None and results[1].problem is None


def test_summary_ranges_and_overlap_marks() -> None:
    inside = RealismStatistics(0.3, 0.2, 0.05, 0.8, 18.0)
    outside = RealismStatistics(0.01, 0.9, -0.2, 1.5, 40.0)
    ranges = summarise([inside, outside])
    coverage = ranges[STATISTIC_NAMES.index("coverage")]
    assert (coverage.low, coverage.high) == (0.01, 0.3)
    assert coverage.real == REAL_RANGES["coverage"]
    assert all(entry.overlaps for entry in ranges)
    missing = summarise([outside])
    assert not any(entry.overlaps for entry in missing)
    table = format_ranges([("in", summarise([inside])), ("out", missing)])
    assert table.count(" *") == len(STATISTIC_NAMES)
    # a range over two photographs overlaps the real one while one of them misses it:
    # the median and the count within say so
    assert (coverage.inside, coverage.count) == (1, 2)
    assert "0.01 - 0.30, median 0.15 (1/2 within)" in format_ranges([("both", ranges)])
    with pytest.raises(SimulateError):
        summarise([])


def test_sharp_drops_miss_the_real_ranges_our_drops_meet() -> None:
    """The issue's claim on bundled photographs at Raindrop's size, 720x480."""
    from lenspair.model.training.synthetic import OUR_DROPS

    images = load_natural_images((480, 720), 3, ("astronaut", "coffee", "rocket"))
    ours = summarise(
        [r.statistics for r in measure_pairs(rendered_pairs(images, OUR_DROPS, 0)) if r.statistics]
    )
    sharp = summarise(
        [
            r.statistics
            for r in measure_pairs(rendered_pairs(images, SHARP_DROPS, 0))
            if r.statistics
        ]
    )
    by_name = {entry.name: entry for entry in ours}
    sharp_by_name = {entry.name: entry for entry in sharp}
    # Real drops brighten and veil the frame; Porav's sharp drops do neither.
    assert by_name["mean_difference"].median > 0.0 > sharp_by_name["mean_difference"].median
    assert by_name["contrast_ratio"].high < 1.0 <= sharp_by_name["contrast_ratio"].high
    assert by_name["coverage"].median > 3 * sharp_by_name["coverage"].median


def test_natural_images_load_offline_at_any_size() -> None:
    images = load_natural_images((48, 72), 1)
    assert list(images) == list(NATURAL_IMAGES)
    assert all(image.shape == (48, 72) and image.dtype == np.uint8 for image in images.values())
    with pytest.raises(SimulateError, match="unknown natural image"):
        load_natural_images(names=("nope",))


def test_cli_measures_a_paired_folder_and_renders_presets(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    folder = tmp_path / "pairs"
    clean = _clean((48, 64)).astype(np.uint16)
    for index in range(3):
        write_image(folder / "input" / f"{index}.png", clean + np.uint16(2000 * (index + 1)))
        write_image(folder / "target" / f"{index}.png", clean)
    out = tmp_path / "realism.json"
    code = main(
        ["realism", str(folder), "--render", "sharp", "--size", "96x64", "--json", str(out)]
    )
    assert code == 0
    printed = capsys.readouterr().out
    assert "pairs (3)" in printed and "sharp (11)" in printed
    assert out.is_file() and '"mean_difference"' in out.read_text()
    with pytest.raises(SystemExit, match="2"):
        main(["realism", "--render", "sharp", "--size", "big"])
    assert "--size" in capsys.readouterr().err


def test_cli_lists_and_skips_pairs_and_images_it_cannot_read(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    import OpenImageIO as oiio

    folder = tmp_path / "pairs"
    clean = _clean((48, 64))
    for index in range(4):
        write_image(folder / "input" / f"{index}.png", clean + np.uint16(2000 * (index + 1)))
        write_image(folder / "target" / f"{index}.png", clean)
    cut = folder / "target" / "1.png"
    cut.write_bytes(cut.read_bytes()[:80])  # truncated
    write_image(folder / "target" / "2.png", clean[:24])  # another size
    write_image(folder / "input" / "4.png", clean)  # no partner: listed, not the end of it
    images = tmp_path / "clean"
    write_image(images / "a.png", _clean((48, 64), seed=1))
    float_tiff = oiio.ImageBuf(oiio.ImageSpec(64, 48, 1, "float"))
    assert float_tiff.write(str(images / "b.tif"))  # a format lenspair does not read
    out = tmp_path / "realism.json"
    argv = [str(folder), "--render", "sharp", "--images", str(images), "--size", "64x48"]
    assert main(["realism", *argv, "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "pairs (2)" in printed and "sharp (1)" in printed
    skipped = [line for line in printed.splitlines() if "skipped" in line]
    assert len(skipped) == 4
    assert any("1.png" in line for line in skipped) and any("2.png" in line for line in skipped)
    assert any("b.tif" in line for line in skipped)
    assert any(line.endswith("skipped input/4.png: no target") for line in skipped)
    rows = json.loads(out.read_text())
    assert len(rows[str(folder)]) == 5  # every pair and orphan accounted for, measured or not
    # named by their names, not by an index ("pair 1")
    assert sorted(row["name"] for row in rows[str(folder)]) == ["0", "1", "2", "3", "input/4.png"]


def test_a_folder_pair_of_grey_beside_colour_or_8_beside_16_bits_is_measured_in_grey(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Statistics are defined on grey [0, 1]: how each file stores it does not matter."""
    clean16 = _clean((48, 64))
    obstructed16 = clean16 + np.uint16(3000)
    folder = tmp_path / "pairs"
    colour = np.repeat(obstructed16[..., None], 3, 2)
    write_image(folder / "input" / "colour.png", colour)  # RGB beside a grey clean image
    write_image(folder / "target" / "colour.png", clean16)
    write_image(folder / "input" / "depth.png", obstructed16)  # 16 bits beside 8
    write_image(folder / "target" / "depth.png", (clean16 // 257).astype(np.uint8))
    out = tmp_path / "realism.json"
    assert main(["realism", str(folder), "--json", str(out)]) == 0
    assert "skipped" not in capsys.readouterr().out
    rows = {row["name"]: row for row in json.loads(out.read_text())[str(folder)]}
    expected = realism_statistics(obstructed16, clean16)
    for name in ("colour", "depth"):
        assert rows[name]["problem"] is None
        assert rows[name]["mean_difference"] == pytest.approx(expected.mean_difference, abs=3e-3)
        assert rows[name]["contrast_ratio"] == pytest.approx(expected.contrast_ratio, abs=2e-2)


def test_a_clean_image_too_small_to_crop_is_skipped(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    images = tmp_path / "clean"
    write_image(images / "a.png", _clean((48, 64), seed=1))
    write_image(images / "dot.png", _clean((1, 1), seed=2))  # no crop of 100x16's aspect fits
    assert main(["realism", "--render", "sharp", "--images", str(images), "--size", "100x16"]) == 0
    printed = capsys.readouterr().out
    assert "skipped dot.png" in printed and "sharp (1)" in printed


def test_clean_images_of_one_name_in_two_folders_are_each_rendered(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # Raindrop's test_a/gt and test_b/gt both hold 0_clean.png: keyed by file name, one was
    # silently dropped (and a skipped one named ambiguously)
    images = tmp_path / "raindrop"
    for seed, split in enumerate(("test_a", "test_b")):
        write_image(images / split / "gt" / "0_clean.png", _clean((48, 64), seed=seed))
    (images / "test_b" / "gt" / "1_clean.png").write_bytes(b"not a png")
    out = tmp_path / "realism.json"
    argv = ["--render", "sharp", "--images", str(images), "--size", "64x48", "--json", str(out)]
    assert main(["realism", *argv]) == 0
    printed = capsys.readouterr().out
    assert "sharp (2)" in printed and "skipped test_b/gt/1_clean.png" in printed
    rows = {row["name"]: row["problem"] for row in json.loads(out.read_text())["sharp"]}
    assert set(rows) == {"test_a/gt/0_clean.png", "test_b/gt/0_clean.png", "test_b/gt/1_clean.png"}
    assert rows["test_a/gt/0_clean.png"] is None and rows["test_b/gt/0_clean.png"] is None


def test_an_empty_split_and_a_folder_without_pairs_say_what_is_wrong(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    dataset = tmp_path / "ds"
    for side in ("input", "target"):
        (dataset / "test" / side).mkdir(parents=True)
    # a lenspair dataset (its card says so): its test split is empty
    (dataset / "dataset.json").write_text('{"format": "lenspair-dataset/1"}\n')
    assert main(["realism", str(dataset)]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert "no pairs to measure (an empty folder or split)" in line  # was "could not be measured"
    photos = tmp_path / "photos"
    write_image(photos / "a.png", _clean((48, 64)))
    assert main(["realism", str(photos)]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert "photos: no paired images (expected input/ + target/" in line


def test_a_folder_given_twice_is_refused_and_a_folder_named_like_a_preset_keeps_its_column(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    folder = tmp_path / "sharp"
    clean = _clean((48, 64)).astype(np.uint16)
    for index in range(2):
        write_image(folder / "input" / f"{index}.png", clean + np.uint16(2000 * (index + 1)))
        write_image(folder / "target" / f"{index}.png", clean)
    assert main(["realism", "sharp", str(folder)]) == 2  # one folder, two spellings
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert "given twice" in line
    out = tmp_path / "realism.json"
    argv = ["realism", "sharp", "--render", "sharp", "--size", "96x64", "--json", str(out)]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "sharp/ (2)" in printed and "sharp (11)" in printed  # two columns, not one
    assert sorted(json.loads(out.read_text())) == ["sharp", "sharp/"]
    dataset = tmp_path / "ds"
    shutil.copytree(folder, dataset / "test")
    for argv in (["ds", "ds/test"], ["--render", "sharp", "sharp"]):  # the same figures twice
        assert main(["realism", *argv]) == 2
        (line,) = capsys.readouterr().err.strip().splitlines()
        assert "given twice" in line or "named twice" in line


def test_untrusted_pixels_count_for_nothing() -> None:
    """A misregistered block marked in mask/ (parallax) is the registration's, not the glass's."""
    clean = _clean((96, 128))
    obstructed = clean.copy()
    obstructed[30:60, 40:90] = np.roll(clean, 7, axis=1)[30:60, 40:90]  # a near object, shifted
    mask = np.zeros((96, 128), np.uint8)
    mask[30:60, 40:90] = 255
    assert realism_statistics(obstructed, clean).input_psnr < 40  # counted without the mask
    masked = realism_statistics(obstructed, clean, mask)
    assert masked.coverage == 0.0 and masked.mean_difference == 0.0
    assert masked.input_psnr == math.inf and masked.contrast_ratio == pytest.approx(1.0)
    brighter = obstructed.copy()
    brighter[mask == 0] += np.uint16(3000)  # the glass brightens the counted pixels only
    stats = realism_statistics(brighter, clean, mask)
    assert stats.mean_difference == pytest.approx(3000 / 65535, rel=1e-3)
    with pytest.raises(SimulateError, match="every pixel is marked untrustworthy"):
        realism_statistics(obstructed, clean, np.ones((96, 128), np.uint8))


def test_a_mask_with_a_channel_axis_is_any_channel_set() -> None:
    # (H, W, 1) built a 3-D mask that indexed 2-D arrays: an IndexError
    clean = _clean((96, 128))
    obstructed = clean.copy()
    obstructed[30:60, 40:90] = np.roll(clean, 7, axis=1)[30:60, 40:90]
    mask = np.zeros((96, 128), np.uint8)
    mask[30:60, 40:90] = 255
    expected = realism_statistics(obstructed, clean, mask)
    assert realism_statistics(obstructed, clean, mask[..., None]) == expected
    colour = np.zeros((96, 128, 3), np.uint8)
    colour[30:60, 40:90, 2] = 255  # set in one channel only
    assert realism_statistics(obstructed, clean, colour) == expected


def test_a_pair_too_large_for_memory_is_skipped_and_the_others_measured(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # an 81-megapixel pair ended the whole report in a MemoryError traceback, exit 1
    clean = _clean()
    real = realism.realism_statistics

    def out_of_memory_for_the_big_one(
        obstructed: np.ndarray, clean: np.ndarray, untrusted: np.ndarray | None = None
    ) -> RealismStatistics:
        if obstructed.shape[0] > 100:
            raise MemoryError
        return real(obstructed, clean, untrusted)

    monkeypatch.setattr(realism, "realism_statistics", out_of_memory_for_the_big_one)
    big = np.zeros((4000, 3000), np.uint16)
    big_pair = ("big", big, big, None)
    results = measure_pairs([big_pair, ("good", clean, clean, None)])
    assert results[0].statistics is None
    assert results[0].problem == "too large to measure in this memory (12 megapixels)"
    assert results[1].statistics is not None


def test_a_label_holding_a_bar_stays_one_table_cell() -> None:
    table = format_ranges([("p|q", summarise([RealismStatistics(0.3, 0.2, 0.05, 0.8, 18.0)]))])
    header, rule = table.splitlines()[:2]
    assert r"p\|q" in header
    assert header.replace(r"\|", "").count("|") == rule.count("|")


def test_cli_reads_the_mask_of_a_paired_folder(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    clean = _clean((48, 64))
    obstructed = clean.copy()
    obstructed[10:30, 10:40] = np.roll(clean, 5, axis=1)[10:30, 10:40]
    mask = np.zeros((48, 64), np.uint8)
    mask[10:30, 10:40] = 255
    folder = tmp_path / "ingested"
    write_image(folder / "input" / "1.png", obstructed)
    write_image(folder / "target" / "1.png", clean)
    write_image(folder / "mask" / "1.png", mask)
    out = tmp_path / "realism.json"
    assert main(["realism", str(folder), "--json", str(out)]) == 0
    (row,) = json.loads(out.read_text())[str(folder)]
    assert row["coverage"] == 0.0 and row["input_psnr"] is None  # identical where trusted
    write_image(folder / "mask" / "1.png", mask[:24])  # another size: this pair skipped
    assert main(["realism", str(folder), "--json", str(out)]) != 0
    assert "does not match" in capsys.readouterr().out


@settings(max_examples=25, deadline=None)
@given(
    step=st.integers(6, 40),
    side=st.integers(1, 5),
    offset_code=st.sampled_from([1000, 6554, 13107]),
)
def test_a_masks_shape_changes_nothing_where_pixels_are_counted(
    step: int, side: int, offset_code: int
) -> None:
    """The untrusted pixels' difference was set to zero and blurred: beside a grid of small
    masks a uniform brightening lost a quarter of its coverage and gained detail."""
    clean = _clean((96, 128))
    obstructed = clean + np.uint16(offset_code)
    mask = np.zeros(clean.shape, np.uint8)
    for top in range(0, 96, step):
        for left in range(0, 128, step):
            mask[top : top + side, left : left + side] = 255
    whole = realism_statistics(obstructed, clean)
    masked = realism_statistics(obstructed, clean, mask)
    assert masked.coverage == whole.coverage
    assert masked.high_frequency == pytest.approx(0.0, abs=1e-6)
    assert masked.mean_difference == pytest.approx(whole.mean_difference, abs=1e-6)


def test_twelve_bit_values_in_16_bit_files_are_measured_widened(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """The folder's reader said "scaled to the full 16-bit range", and realism measured the
    values as stored: a 0.10 brightening read as 0.006 (12-bit values on a 16-bit scale)."""
    rng = np.random.default_rng(0)
    clean = rng.integers(1000, 3000, (48, 64)).astype(np.uint16)  # 12-bit values
    brighter = clean + np.uint16(410)
    folder = tmp_path / "b12"
    write_image(folder / "input" / "a.png", brighter)
    write_image(folder / "target" / "a.png", clean)
    mixed = tmp_path / "mix12"  # an 8-bit obstructed frame beside a 12-bit clean one
    write_image(mixed / "input" / "a.png", (brighter // 16).astype(np.uint8))
    write_image(mixed / "target" / "a.png", clean)
    out = tmp_path / "realism.json"
    assert main(["realism", str(folder), str(mixed), "--json", str(out)]) == 0
    assert "hold 12-bit values" in caplog.text
    rows = json.loads(out.read_text())
    (row,) = rows[str(folder)]
    assert row["mean_difference"] == pytest.approx(410 / 4095, abs=1e-3)
    assert row["coverage"] == 1.0
    (row,) = rows[str(mixed)]
    assert row["mean_difference"] == pytest.approx(410 / 4095, abs=5e-3)
    assert row["contrast_ratio"] == pytest.approx(1.0, abs=0.02)


def test_clean_images_of_twelve_bits_are_rendered_on_widened(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """A Mono12 camera's frames as clean images: drops were rendered on a nearly black
    scene (4095 of 65535), so the statistics measured drops on black."""
    bright = np.full((96, 128), 0.5)
    bright[::8] = 0.8
    images = tmp_path / "clean"
    write_image(images / "twelve.png", np.round(bright * 4095).astype(np.uint16))
    write_image(images / "eight.png", np.round(bright * 255).astype(np.uint8))
    out = tmp_path / "realism.json"
    args = ["realism", "--render", "ours", "--images", str(images), "--size", "128x96"]
    assert main([*args, "--json", str(out), "--seed", "3"]) == 0
    assert "the clean images are scaled to the full 16-bit range" in caplog.text
    rows = {row["name"]: row for row in json.loads(out.read_text())["ours"]}
    twelve = next(row for name, row in rows.items() if "twelve" in name)
    eight = next(row for name, row in rows.items() if "eight" in name)
    # the same scene at either depth: the same contrast the glass takes away
    assert twelve["contrast_ratio"] == pytest.approx(eight["contrast_ratio"], abs=0.05)

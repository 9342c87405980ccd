import re
from pathlib import Path

import numpy as np
import pytest

from lenspair.core.bitdepth import widen
from lenspair.core.imagewrite import write_image
from lenspair.dataset.build import build_dataset
from lenspair.dataset.config import DatasetConfig, SplitConfig
from lenspair.dataset.errors import DatasetError
from lenspair.dataset.layouts import detect_layout, natural_key
from lenspair.dataset.manifest import read_manifest
from lenspair.dataset.readers import PairedDataset, open_paired
from tests.dataset.dataset_synth import RecordingFactory


def _image(value: int, shape: tuple[int, ...] = (8, 12, 3), dtype: type = np.uint8) -> np.ndarray:
    return np.full(shape, value, dtype)


def _write(folder: Path, names: dict[str, int], dtype: type = np.uint8) -> None:
    for name, value in names.items():
        write_image(folder / name, _image(value, dtype=dtype))


def test_lenspair_layout_root_with_split_and_split_folder(
    recording: RecordingFactory, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    sources = [recording("rec_a", n=6, masked=True, clean=(2,)), recording("rec_b", n=6, seed=1)]
    config = DatasetConfig(split=SplitConfig(fractions=(0.5, 0.5, 0.0), group_by="recording"))
    ds = build_dataset(sources, tmp_path / "DS", config).out
    rows = read_manifest(ds / "manifest.jsonl")
    caplog.clear()
    for split in ("train", "val"):
        data = open_paired(ds, split)
        assert not caplog.messages  # its own mask/ needs no word (a generic folder's does)
        assert data.layout == "lenspair"
        expected = sorted((r for r in rows if r.split == split), key=lambda r: natural_key(r.name))
        assert data.names == tuple(r.name for r in expected)
        item = data[0]
        assert item.input.dtype == np.uint8 and item.input.shape == (48, 64, 3)
        assert item.target.shape == item.input.shape
        assert item.difficulty == expected[0].difficulty
        assert (item.mask is not None) == (expected[0].recording == "rec_a")
        if item.mask is not None:
            assert item.mask.shape == (48, 64)
        assert open_paired(ds / split).names == data.names
    everything = [item for split in ("train", "val") for item in open_paired(ds, split)]
    assert sum(1 for item in everything if item.difficulty == "clean") == 1
    with pytest.raises(DatasetError, match="choose one of test, train, val"):
        open_paired(ds)
    assert len(open_paired(ds, "test")) == 0  # an empty split of a lenspair dataset is fine
    with pytest.raises(DatasetError, match="no split folder 'dev'"):
        open_paired(ds, "dev")
    photos = ds.parent / "photos"  # a folder of images, not pairs: said so, not "no split"
    photos.mkdir()
    (photos / "a.png").write_bytes(b"")
    with pytest.raises(DatasetError, match=r"photos: no paired images \(expected input/"):
        open_paired(photos, "test")
    train = open_paired(ds, "train")
    assert len(train.select({"clean"})) + len(train.select({"easy", "medium", "hard"})) == len(
        train
    )


def test_generic_paired_folders(tmp_path: Path) -> None:
    _write(tmp_path / "a" / "input", {"10.png": 1, "2.png": 2, "1.png": 3})
    _write(tmp_path / "a" / "target", {"10.png": 4, "2.png": 5, "1.png": 6})
    data = open_paired(tmp_path / "a")
    assert data.layout == "paired" and data.names == ("1", "2", "10")
    assert int(data[1].input[0, 0, 0]) == 2 and int(data[1].target[0, 0, 0]) == 5
    assert data[0].difficulty is None and data[0].mask is None

    _write(tmp_path / "b" / "lq", {"x.png": 1, "y.png": 2}, np.uint16)
    _write(tmp_path / "b" / "gt", {"x.png": 3}, np.uint16)
    _write(tmp_path / "b" / "gt", {"y.jpg": 2})
    (tmp_path / "b" / "gt" / ".DS_Store").write_bytes(b"junk")
    data = open_paired(tmp_path / "b")
    assert data.layout == "paired" and data.names == ("x", "y")
    assert data[0].input.dtype == data[0].target.dtype == np.uint16
    target = re.escape(str(tmp_path / "b" / "gt" / "y.jpg"))
    with pytest.raises(DatasetError, match=rf"does not match {target} "):  # named in full
        data[1]  # uint16 input against a uint8 target


def test_unpaired_names_are_listed(tmp_path: Path) -> None:
    _write(tmp_path / "input", {f"{i}.png": i for i in range(8)})
    _write(tmp_path / "target", {f"{i}.png": i for i in range(1, 8)} | {"extra.png": 1})
    with pytest.raises(DatasetError, match=r"2 unpaired file\(s\): input/0.png \(no target\)"):
        open_paired(tmp_path)
    with pytest.raises(DatasetError, match=r"target/extra.png \(no input\)"):
        open_paired(tmp_path)


def test_raindrop_layout_with_png_and_jpg(tmp_path: Path) -> None:
    root = tmp_path / "raindrop"
    _write(root / "train" / "data", {"0_rain.png": 10, "1_rain.png": 11, "10_rain.png": 12})
    _write(root / "train" / "gt", {"0_clean.png": 20, "1_clean.png": 21, "10_clean.png": 22})
    _write(root / "test_a" / "data", {"3_rain.jpg": 30, "4_rain.png": 40})
    _write(root / "test_a" / "gt", {"3_clean.jpg": 31, "4_clean.jpg": 41})
    train = open_paired(root, "train")
    assert train.layout == "raindrop" and train.names == ("0", "1", "10")
    assert int(train[2].input[0, 0, 0]) == 12 and int(train[2].target[0, 0, 0]) == 22
    test_a = open_paired(root / "test_a")
    assert test_a.names == ("3", "4")
    assert test_a[0].input.dtype == np.uint8 and test_a[0].input.shape == (8, 12, 3)
    with pytest.raises(DatasetError, match="choose one of test_a, train"):
        open_paired(root)
    _write(root / "test_a" / "data", {"5_rain.png": 50})
    with pytest.raises(DatasetError, match=r"data/5_rain.png \(no gt\)"):
        open_paired(root, "test_a")


def test_layout_detection_and_errors(tmp_path: Path) -> None:
    (tmp_path / "empty").mkdir()
    assert detect_layout(tmp_path / "empty") is None
    with pytest.raises(DatasetError, match="no paired images found"):
        open_paired(tmp_path / "empty")
    with pytest.raises(DatasetError, match="not a folder"):
        open_paired(tmp_path / "missing")
    (tmp_path / "p" / "input").mkdir(parents=True)
    (tmp_path / "p" / "target").mkdir()
    with pytest.raises(DatasetError, match="no images in input/"):
        open_paired(tmp_path / "p")
    _write(tmp_path / "d" / "input", {"a.png": 1, "a.jpg": 1})
    _write(tmp_path / "d" / "target", {"a.png": 1})
    with pytest.raises(DatasetError, match="name 'a' also used by"):
        open_paired(tmp_path / "d")


def test_dataset_is_map_style(tmp_path: Path) -> None:
    _write(tmp_path / "input", {"a.png": 1, "b.png": 2})
    _write(tmp_path / "target", {"a.png": 1, "b.png": 2})
    data = open_paired(tmp_path)
    assert isinstance(data, PairedDataset) and len(data) == 2
    assert [item.name for item in data] == ["a", "b"]
    assert "pairs=2" in repr(data)


def test_input_and_target_are_read_even_beside_an_lq_folder(tmp_path: Path) -> None:
    """detect_layout finds input/ + target/ first; the reader read lq/ + gt/ whenever lq/
    existed: the wrong pairs without a word, or a traceback for a missing gt/."""
    _write(tmp_path / "a" / "input", {"1.png": 1, "2.png": 2, "3.png": 3})
    _write(tmp_path / "a" / "target", {"1.png": 4, "2.png": 5, "3.png": 6})
    _write(tmp_path / "a" / "lq", {"9.png": 7})
    _write(tmp_path / "a" / "gt", {"9.png": 8})
    assert open_paired(tmp_path / "a").names == ("1", "2", "3")
    (tmp_path / "b" / "lq").mkdir(parents=True)  # an empty lq/ and no gt/
    _write(tmp_path / "b" / "input", {"1.png": 1})
    _write(tmp_path / "b" / "target", {"1.png": 2})
    assert open_paired(tmp_path / "b").names == ("1",)


def test_a_mask_of_another_size_is_found_from_headers_and_on_reading(tmp_path: Path) -> None:
    """It passed both and ended a training run mid-epoch with a tensor-size traceback."""
    _write(tmp_path / "p" / "input", {"1.png": 1, "2.png": 2})
    _write(tmp_path / "p" / "target", {"1.png": 3, "2.png": 4})
    write_image(tmp_path / "p" / "mask" / "1.png", np.zeros((8, 12), np.uint8))
    write_image(tmp_path / "p" / "mask" / "2.png", np.zeros((5, 5), np.uint8))
    data = open_paired(tmp_path / "p")
    assert data[0].mask is not None and data[0].mask.shape == (8, 12)
    mask = re.escape(str(tmp_path / "p" / "mask" / "2.png"))
    headers, problems = data.header_problems()
    assert set(headers) == {0} and set(problems) == {1}  # 1 bad pair of 2
    assert re.fullmatch(rf"{mask}: mask 5x5 does not match 2\.png 12x8", problems[1])
    with pytest.raises(DatasetError, match=rf"^{mask}: mask 5x5 does not match 2\.png 12x8$"):
        data[1]


@pytest.mark.parametrize(
    ("name", "text"),
    [("manifest.jsonl", '{"image": "a.png", "label": 3}\n'), ("dataset.json", '{"images": []}')],
)
def test_another_tools_manifest_beside_a_paired_folder_leaves_it_paired(
    tmp_path: Path, name: str, text: str
) -> None:
    """Any manifest.jsonl or dataset.json in the parent made the folder a lenspair split,
    and the foreign manifest was then read strictly: the pairs could not be opened."""
    _write(tmp_path / "pairs" / "input", {"1.png": 1, "2.png": 2})
    _write(tmp_path / "pairs" / "target", {"1.png": 3, "2.png": 4})
    (tmp_path / name).write_text(text)
    assert detect_layout(tmp_path / "pairs") == "paired"
    data = open_paired(tmp_path / "pairs")
    assert data.layout == "paired" and data.names == ("1", "2")
    assert data[0].difficulty is None
    assert open_paired(tmp_path, "pairs").names == ("1", "2")


def test_a_lenspair_manifest_without_a_card_still_reads_as_a_lenspair_dataset(
    recording: RecordingFactory, tmp_path: Path
) -> None:
    """The card decides when it is there; a dataset that lost it keeps its difficulties."""
    config = DatasetConfig(split=SplitConfig(fractions=(1.0, 0.0, 0.0)))
    ds = build_dataset([recording("rec_a", n=4)], tmp_path / "DS", config).out
    (ds / "dataset.json").unlink()
    train = open_paired(ds, "train")
    assert train.layout == "lenspair" and train[0].difficulty is not None
    (ds / "dataset.json").write_text('{"images": []}')  # another tool's card: it decides
    assert open_paired(ds, "train").layout == "paired"


def test_a_header_mismatch_names_the_target_by_its_path(tmp_path: Path) -> None:
    """It named the input by path and the target by bare name ("... does not match 0.png")."""
    _write(tmp_path / "input", {"0.png": 1})
    _write(tmp_path / "target", {"0.png": 1}, np.uint16)
    target = re.escape(str(tmp_path / "target" / "0.png"))
    headers, problems = open_paired(tmp_path).header_problems()
    assert headers == {} and set(problems) == {0}
    assert re.search(rf"0\.png: 12x8x3 uint8 does not match {target} 12x8x3", problems[0])


def test_files_and_folders_left_out_are_said(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """.bmp files (which restore reads) and sub-folders were passed over without a word, and a
    folder of them alone was "no images in input/"."""
    for side in ("input", "target"):
        _write(tmp_path / "p" / side, {"0.bmp": 1, "1.png": 2, "sub/2.png": 3})
    (tmp_path / "p" / "input" / "notes.txt").write_text("x")
    with caplog.at_level("WARNING"):
        data = open_paired(tmp_path / "p")
    assert data.names == ("0", "1") and int(data[0].input[0, 0, 0]) == 1
    assert caplog.messages == [
        f"{tmp_path / 'p'}: left out of the pairs: 1 file(s) not read as images (e.g. "
        "input/notes.txt) and 2 sub-folder(s), not searched (e.g. input/sub/); images are files "
        "ending .bmp, .jfif, .jpe, .jpeg, .jpg, .pbm, .pgm, .png, .pnm, .ppm, .tif, .tiff"
    ]
    notes: list[str] = []  # or kept for a training run to log
    caplog.clear()
    open_paired(tmp_path / "p", notes=notes)
    assert len(notes) == 1 and not caplog.messages
    _write(tmp_path / "q" / "input", {"sub/0.png": 1})
    (tmp_path / "q" / "input" / "0.webp").write_bytes(b"RIFF")
    (tmp_path / "q" / "target").mkdir()
    with pytest.raises(
        DatasetError,
        match=r"no images in input/ \(it holds 1 file\(s\) not read as images \(e\.g\. "
        r"input/0\.webp\) and 1 sub-folder\(s\), not searched \(e\.g\. input/sub/\); images "
        r"are files ending \.bmp, ",
    ):
        open_paired(tmp_path / "q")


def test_a_generic_mask_folder_is_said_once(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """Another project's mask/ (often: where the rain is) was silently left out of the loss
    and the scores, which then rose."""
    _write(tmp_path / "p" / "input", {"1.png": 1, "2.png": 2})
    _write(tmp_path / "p" / "target", {"1.png": 3, "2.png": 4})
    for name in ("1.png", "2.png"):
        write_image(tmp_path / "p" / "mask" / name, np.zeros((8, 12), np.uint8))
    with caplog.at_level("WARNING"):
        data = open_paired(tmp_path / "p")
    assert data[0].mask is not None  # still used, in lenspair's meaning
    assert caplog.messages == [
        f"{tmp_path / 'p' / 'mask'}/: 2 masks mark pixels left out of the loss and the scores "
        "(lenspair's meaning: pixels the registration cannot vouch for); remove or rename mask/ "
        "if yours marks the anomaly"
    ]


def test_an_ingested_recording_s_own_mask_and_depth_are_lenspair_s(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """`lenspair realism ingested/rain` (the README's example) told the user to remove or
    rename the recording's mask/ (capture-ingest's own parallax mask), and a dark ingested
    16-bit recording (already widened) read as 12-bit and was brightened 16x again."""
    folder = tmp_path / "ingested" / "rain"
    _write(folder / "input", {"1.png": 1000, "2.png": 2000}, np.uint16)
    _write(folder / "target", {"1.png": 1100, "2.png": 2100}, np.uint16)
    write_image(folder / "mask" / "1.png", np.full((8, 12), 255, np.uint8))
    (folder / "pairs.jsonl").write_text("")
    (folder / "report.json").write_text("{}")
    with caplog.at_level("WARNING"):
        data = open_paired(folder)
    assert caplog.messages == []
    assert data[0].mask is not None and data.bits == 16
    assert int(data[1].input.max()) == 2000  # as ingested: not widened a second time


def test_ten_or_twelve_bit_values_in_16_bit_files_are_widened(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """train and eval took them as 16-bit (near-black frames, scores inflated by ~24 dB)
    while restore widened them: the network saw other frames than it restores."""
    _write(tmp_path / "input", {"a.png": 100, "b.png": 4000}, np.uint16)
    _write(tmp_path / "target", {"a.png": 200, "b.png": 4095}, np.uint16)
    with caplog.at_level("WARNING"):
        data = open_paired(tmp_path)
    item = data[1]
    assert int(item.target.max()) == 65535  # full scale stays full scale
    assert np.array_equal(item.input, widen(np.full((8, 12, 3), 4000, np.uint16), 12))
    assert data.bits == 12 and len(caplog.messages) == 1
    assert "16-bit images hold 12-bit values (none above 4095 in 4 sampled" in caplog.messages[0]
    _write(tmp_path / "input", {"b.png": 5000}, np.uint16)  # a pair the sample missed
    with pytest.raises(DatasetError, match=r"b\.png: holds values above 4095"):
        data[1]  # refused, not clipped
    _write(tmp_path / "input", {"b.png": 40000}, np.uint16)  # a genuine 16-bit folder
    assert open_paired(tmp_path).bits == 16
    assert int(open_paired(tmp_path)[1].input.max()) == 40000


def test_names_that_differ_in_leading_zeros_come_in_one_order(tmp_path: Path) -> None:
    """Equal numbers (``img1``, ``img01``) made equal keys: pairs sorted from a set came in
    an order that changed with Python's string hashing, and a seeded shuffle drew others."""
    import itertools

    names = ["img1", "img01", "img001", "x2", "x02", "img2"]
    orders = {tuple(sorted(p, key=natural_key)) for p in itertools.permutations(names)}
    assert orders == {("img001", "img01", "img1", "img2", "x02", "x2")}
    for name in names:
        for kind in ("input", "target"):
            write_image(tmp_path / kind / f"{name}.png", np.zeros((8, 8), np.uint8))
    assert open_paired(tmp_path).names == ("img001", "img01", "img1", "img2", "x02", "x2")

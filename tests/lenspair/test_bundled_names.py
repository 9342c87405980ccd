"""Bundled samples by name on the command line, from any folder."""

from pathlib import Path

import pytest

from lenspair.cli import main
from lenspair.commands.argtypes import detector_file
from lenspair.core.samples import file_or_sample, sample_path


def test_a_name_is_the_bundled_sample_unless_such_a_file_exists(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)  # not the repository root: calib_samples/ is not here
    assert file_or_sample("rain", ".yaml") == sample_path("rain.yaml")
    assert file_or_sample("rain.yaml", ".yaml") == sample_path("rain.yaml")
    assert detector_file("detector.pt") == sample_path("detector.pt")
    (tmp_path / "rain.yaml").write_text("mine")
    assert file_or_sample("rain.yaml", ".yaml") == Path("rain.yaml")  # the user's file wins
    assert file_or_sample("nowhere/rain.yaml", ".yaml") == Path("nowhere/rain.yaml")  # a path
    assert file_or_sample("no_such_scene", ".yaml") == Path("no_such_scene")  # fails later


def test_a_bare_name_beside_a_file_of_that_name_says_which_it_took(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """`simulate rain` in a folder holding the user's rain.yaml rendered the bundled scene,
    and said nothing of the file it passed over."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "rain.yaml").write_text("mine")
    with caplog.at_level("WARNING"):
        assert file_or_sample("rain", ".yaml") == sample_path("rain.yaml")
    assert caplog.messages == [
        "rain: the bundled sample rain.yaml; rain.yaml in this folder is not read (give "
        "rain.yaml for it)"
    ]


def test_simulate_a_bundled_scene_by_name(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    assert main(["simulate", "rain", "--out", "rec", "--frames", "2"]) == 0
    assert len(list((tmp_path / "rec" / "mav0" / "cam1" / "data").glob("*.png"))) == 2

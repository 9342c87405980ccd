"""What ``train-detector`` and ``detect`` tell their user: stop hint, help, files not judged."""

import csv
import re
from pathlib import Path

import numpy as np
import pytest

from lenspair.cli import TERMINATED, Terminated, main
from lenspair.core.imagewrite import write_image
from lenspair.model.detection.unjudged import unjudged_files, unjudged_note
from lenspair.model.inference.unread_files import unrestored_note
from tests.images import texture


@pytest.mark.parametrize("simulated_set", [False, True])
def test_a_stopped_train_detector_says_a_rerun_trains_from_the_start(
    simulated_set: bool, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    # "rerun to resume": training keeps no checkpoint, a rerun starts again at step 0
    import lenspair.commands.train_detector

    def terminated(args: object) -> int:
        raise Terminated

    monkeypatch.setattr(lenspair.commands.train_detector, "run", terminated)
    extra = ["--simulated-set", "sims"] if simulated_set else []
    assert main(["train-detector", "--synthetic", "8", "--out", "run", *extra]) == TERMINATED
    [said] = capsys.readouterr().err.strip().splitlines()
    assert said.startswith("lenspair train-detector: terminated; ")
    assert "resume" not in said and "trains from the start" in said
    assert ("reusing the recordings already rendered in sims" in said) is simulated_set


def test_train_detector_help_states_the_synthetic_defaults(
    capsys: pytest.CaptureFixture[str],
) -> None:
    # "--synthetic N  synthetic frames", "--clean-images  clean images for --synthetic"
    with pytest.raises(SystemExit) as exited:
        main(["train-detector", "--help"])
    assert exited.value.code == 0
    options = " ".join(capsys.readouterr().out.split()).split("options:")[1]
    found = re.search(r" --synthetic N (.*) --clean-images DIR (.*) --simulated-set DIR ", options)
    assert found is not None
    synthetic, clean = found.groups()
    assert "(default 0: none)" in synthetic
    assert "--synthetic" in clean and "(default: the simulator's textures)" in clean


@pytest.mark.parametrize(
    ("options", "steps", "seconds"),
    [
        ([], 600, None),
        (["--minutes", "5"], None, 300.0),  # was 600 steps: 15 s of a 5-minute budget
        (["--steps", "50"], 50, None),
        (["--steps", "50", "--minutes", "5"], 50, 300.0),  # whichever comes first
        # units, as train's --max-seconds and tradeoff's --budget take them: '5m' was
        # "expected a number"
        (["--minutes", "5m"], None, 300.0),
        (["--minutes", "90s"], None, 90.0),
        (["--minutes", "1h"], None, 3600.0),
    ],
)
def test_train_detector_minutes_alone_sets_no_step_limit(
    options: list[str],
    steps: int | None,
    seconds: float | None,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import lenspair.model.detection.run
    from lenspair.model.detection.train import DetectorTraining

    given: list[DetectorTraining] = []

    def recorded(
        out: Path, sources: object, spec: object, settings: DetectorTraining, **_: object
    ) -> dict[str, object]:
        given.append(settings)
        return {}

    monkeypatch.setattr(lenspair.model.detection.run, "run_training", recorded)
    argv = ["train-detector", "--synthetic", "8", "--out", str(tmp_path / "run"), *options]
    assert main(argv) == 0
    [settings] = given
    assert (settings.steps, settings.max_seconds) == (steps, seconds)


def test_train_detector_help_states_what_ends_training(
    capsys: pytest.CaptureFixture[str],
) -> None:
    with pytest.raises(SystemExit):
        main(["train-detector", "--help"])
    options = " ".join(capsys.readouterr().out.split()).split("options:")[1]
    found = re.search(
        r" --steps N (.*) --batch-size BATCH_SIZE (.*) --minutes TIME (.*) --seed", options
    )
    assert found is not None
    steps, _, minutes = found.groups()
    assert "default: 600" in steps and "no step limit with --minutes" in steps
    assert "whichever comes first" in steps and "whichever comes first" in minutes


def test_train_detector_synthetic_given_a_folder_points_to_clean_images(
    capsys: pytest.CaptureFixture[str],
) -> None:
    # "train --synthetic DIR" takes a folder; here the frame count: "invalid int value"
    with pytest.raises(SystemExit) as exited:
        main(["train-detector", "DS", "--synthetic", "DS/train/target", "--out", "run"])
    assert exited.value.code == 2
    [said] = capsys.readouterr().err.strip().splitlines()
    assert said.startswith("lenspair train-detector: error: argument --synthetic: ")
    assert "a number of frames" in said and "'DS/train/target'" in said
    assert "goes in --clean-images DIR" in said


@pytest.fixture
def mixed_folder(tmp_path: Path) -> Path:
    """One frame among a bag, a video, a WebP image, a note and a recording's listing."""
    folder = tmp_path / "in"
    write_image(folder / "f00.png", (texture((120, 180), 0) * 255).astype(np.uint8))
    for name in ("rain.bag", "clip.mp4", "sub/still.webp", "notes.txt", "sub/data.csv"):
        (folder / name).parent.mkdir(parents=True, exist_ok=True)
        (folder / name).write_bytes(b"not an image")
    return folder


def test_detect_names_the_files_of_a_folder_it_does_not_judge(
    mixed_folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # "1 frame judged (0 not: ...)", and not a word of the bag or the video
    out = tmp_path / "out"
    assert main(["detect", "detector.pt", str(mixed_folder), "--out", str(out)]) == 0
    said = capsys.readouterr()
    warnings = [line for line in said.err.splitlines() if "warning" in line]
    assert warnings == [
        f"lenspair detect: warning: {mixed_folder / 'clip.mp4'}: a video, not judged: detect "
        "takes its frames as images",
        f"lenspair detect: warning: {mixed_folder / 'rain.bag'}: a bag, not judged: detect it "
        "as an INPUT of its own",
        f"lenspair detect: warning: {mixed_folder / 'sub/still.webp'}: .webp images are not "
        "read, not judged: convert it to PNG or TIFF to detect it",
    ]
    assert "1 frame judged" in said.out and "3 files that may hold frames not judged" in said.out
    with (out / "detections.csv").open() as handle:
        assert [row["name"] for row in csv.DictReader(handle)] == ["f00.png"]


def test_detect_names_the_files_restore_names(mixed_folder: Path) -> None:
    """The same files as restore's problems: only the wording differs (not judged, not copied)."""
    files = sorted(p for p in mixed_folder.rglob("*") if p.is_file())
    named = [p for p in files if unjudged_note(p) is not None]
    assert named == [p for p in files if unrestored_note(p) is not None]
    assert [p.name for p in named] == ["clip.mp4", "rain.bag", "still.webp"]


def test_only_folder_inputs_are_looked_through(mixed_folder: Path) -> None:
    judged = [mixed_folder / "f00.png"]
    assert len(unjudged_files(mixed_folder, "folder", judged)) == 3
    assert unjudged_files(mixed_folder / "f00.png", "image", judged) == []
    assert unjudged_files(mixed_folder / "rain.bag", "rosbag1", []) == []


def test_the_detectors_clean_images_of_twelve_bits_are_widened(tmp_path: Path) -> None:
    """A Mono12 camera's frames as clean images: the detector learned drops on near black."""
    from lenspair.model.detection.sources import clean_images

    scene = np.round(texture((48, 64), seed=2) * 4095).astype(np.uint16)  # 12-bit values
    write_image(tmp_path / "clean" / "twelve.png", scene)
    (image,) = clean_images(tmp_path / "clean")
    assert image.dtype == np.uint16 and int(image.max()) > 32768  # the scene's bright end

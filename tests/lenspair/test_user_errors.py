"""No traceback for any user error: every subcommand, every kind of bad input.

Each case runs the CLI in-process with one bad file or option value and
asserts exit code 2 and exactly one line on stderr that names the file or
option. The table covers every entry of ``lenspair.cli.COMMANDS`` (a test
checks), so a new command must add its bad inputs here.
"""

import logging
import os
from collections.abc import Callable
from pathlib import Path

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from lenspair.cli import COMMANDS, build_parser, main
from lenspair.commands.argtypes import expand_topics
from lenspair.core.errors import first_line, first_text_line
from tests.model.train_fixtures import write_split_dataset

# Bad files, by kind: (file name, writer). "unreadable" is a folder where a file
# is expected when running as root (root reads any mode-000 file).
BAD_FILES: dict[str, Callable[[Path], None]] = {
    "missing": lambda path: None,
    "empty": lambda path: path.write_bytes(b""),
    "folder": lambda path: path.mkdir(),
    "binary": lambda path: path.write_bytes(b"\x89PNG\r\n\x1a\n\x00\xff garbage"),
    "malformed-yaml": lambda path: path.write_text("a: [1, 2\n  b: }\n"),
    "wrong-yaml": lambda path: path.write_text("- just\n- a list\n"),
}


def _unreadable(path: Path) -> None:
    path.write_text("rig: {}\n")
    path.chmod(0)
    if os.access(path, os.R_OK):  # root: a mode-000 file is still readable
        path.chmod(0o644)
        path.unlink()
        path.mkdir()


BAD_FILES["unreadable"] = _unreadable

# command -> argument lists where BAD stands for the bad file and the named
# token must appear in the message. DS is a valid tiny dataset, OUT a fresh folder,
# CKPT a valid tiny restoration checkpoint, DET a valid detector checkpoint and
# IMGS a folder of valid images (so that the bad file is the only problem).
FILE_CASES: dict[str, list[list[str]]] = {
    "simulate": [["BAD", "--out", "OUT"]],
    "calibrate": [
        [
            "BAD",
            "--board",
            "chessboard:9x6:0.025",
            "--model",
            "pinhole-radtan",
            "--out",
            "OUT/c.yaml",
        ]
    ],
    "capture-ingest": [["BAD", "--out", "OUT"]],
    "dataset-build": [["BAD", "--out", "OUT"], ["--verify", "BAD"]],
    "train": [
        ["DS", "--out", "OUT", "--config", "BAD"],
        ["DS", "--out", "OUT", "--init", "BAD", "--crop-size", "24"],  # DS: 48x32 images
        ["BAD", "--out", "OUT"],
    ],
    "eval": [["BAD", "--data", "DS"]],
    "tradeoff": [["BAD", "--out", "OUT"], ["DS", "--out", "OUT", "--config", "BAD"]],
    "export": [["BAD", "--onnx", "OUT/m.onnx"]],
    "demo": [],  # demo reads only bundled files; its options are covered below
    "restore": [
        ["BAD", "IMGS", "--out", "OUT"],
        ["CKPT", "BAD", "--out", "OUT"],
        ["CKPT", "IMGS", "--out", "OUT", "--only-obstructed", "BAD"],
    ],
    "detect": [["BAD", "IMGS", "--out", "OUT"], ["DET", "BAD", "--out", "OUT"]],
    "realism": [["BAD"], ["--render", "ours", "--images", "BAD"]],
    "train-detector": [
        ["BAD", "--out", "OUT"],
        ["--recordings", "BAD", "--out", "OUT"],
        ["--synthetic", "2", "--clean-images", "BAD", "--out", "OUT"],
    ],
}

# (argv, token the message must name)
OPTION_CASES: list[tuple[list[str], str]] = [
    (["simulate", "calib_samples/rain.yaml", "--out", "OUT", "--frames", "x"], "--frames"),
    (["simulate", "nope", "--out", "OUT"], "nor a bundled scene (charuco, chessboard"),
    (["simulate", "calib_samples/rain.yaml", "--out", "OUT", "--frames", "-3"], "--frames"),
    (["simulate", "calib_samples/rain.yaml", "--out", "OUT", "--frames", "0"], "--frames"),
    (
        ["calibrate", "DS", "--board", "nonsense", "--model", "pinhole-radtan", "--out", "OUT/c"],
        "board",
    ),
    (["calibrate", "DS", "--board", "x", "--model", "pinhole", "--out", "OUT/c"], "--model"),
    (["capture-ingest", "DS", "--out", "OUT", "--workers", "0"], "--workers"),
    (["dataset-build", "DS", "--out", "OUT", "--splits", "1,2"], "--splits"),
    (["dataset-build", "DS", "--out", "OUT", "--splits", "80,10,10"], "--splits: must sum to 1"),
    (["dataset-build", "DS", "--out", "OUT", "--splits", "0,.5,.5"], "--splits: the train"),
    (["dataset-build", "DS", "--out", "OUT", "--workers", "-1"], "--workers"),
    (["dataset-build", "DS", "--out", "x" * 300], "File name too long"),  # was a traceback
    (["eval", "CKPT", "--data", "DS", "--out", "y" * 300], "File name too long"),
    (["train", "DS", "--out", "OUT", "--batch-size", "0"], "--batch-size"),
    # counts past C's int ended in OverflowError tracebacks (torch, multiprocessing)
    (["train", "DS", "--out", "OUT", "--batch-size", "99999999999999999999"], "at most"),
    (["capture-ingest", "DS", "--out", "OUT", "--workers", "99999999999999999999"], "--workers"),
    (["train-detector", "--out", "OUT", "--synthetic", "2", "--threads", "99999"], "--threads"),
    (
        ["train-detector", "--out", "OUT", "--synthetic", "2", "--batch-size", "9" * 20],
        "--batch-size",
    ),
    # an allocator's traceback after the data was gathered
    (
        ["train-detector", "--out", "OUT", "--synthetic", "2", "--batch-size", "100000"],
        "--batch-size 100000 of --input-size 270x180 is 4.86e+09 pixels a step",
    ),
    (["train-detector", "--out", "OUT", "--synthetic", "2", "--input-size", "9999x99"], "1920"),
    # rendered into the current folder; a file given: "Not a directory" with exit 1
    (["train-detector", "--out", "OUT", "--simulated-set", ""], "--simulated-set: an empty"),
    (["train-detector", "--out", "OUT", "--simulated-set", "CKPT"], "--simulated-set"),
    (["dataset-build", "DS", "--out", "OUT", "--seed", "-1"], "--seed"),  # was accepted
    (["simulate", "calib_samples/rain.yaml", "--out", ""], "--out: an empty name"),
    (["simulate", "s" * 300, "--out", "OUT"], "File name too long"),  # a traceback, then exit 1
    (["train", "DS", "--out", "DS"], "the data trained on"),  # replaced the dataset's config
    (["capture-ingest", "DS", "--out", "DS"], "inside the recording"),  # restore read it back
    # counts that started endless work, or a MemoryError traceback
    (["eval", "CKPT", "--data", "DS", "--latency-runs", "9" * 20], "--latency-runs"),
    (["tradeoff", "DS", "--out", "OUT", "--latency-runs", "100000"], "at most 10000"),
    (["train-detector", "--out", "OUT", "--synthetic", "9" * 20], "at most 1000000 frames"),
    (["train", "DS", "--out", "OUT", "--init", "OUT/none.pt"], "--init"),
    (["calibrate", "DS", "--board", "x", "--model", "pinhole-equi", "--out", "/proc/x/c"], "x/c"),
    (["detect", "IMGS", "OUT/detector.pt", "--out", "OUT/d"], "the model comes first"),
    (["train", "DS", "--out", "OUT", "--crop-size", "16"], "--crop-size): expected >= 24"),
    (["tradeoff", "DS", "--out", "OUT", "--crop-size", "16"], "--crop-size): expected >= 24"),
    (["train", "DS", "--out", "OUT", "--device", "tpu"], "--device"),
    (["tradeoff", "DS", "--out", "OUT", "--budget", "abc"], "--budget"),
    (["tradeoff", "DS", "--out", "OUT", "--variants", ","], "--variants"),
    (["tradeoff", "DS", "--out", "OUT", "--seeds", "-1"], "--seeds"),
    (["tradeoff", "DS", "--out", "OUT", "--lr-decay", "nan"], "--lr-decay"),
    (["tradeoff", "DS", "--out", "OUT", "--lr-decay", "1.5"], "--lr-decay"),
    (["train", "DS", "--out", "OUT", "--seed", "-1"], "seed"),
    (["train", "DS", "--out", "OUT", "--max-seconds", "inf"], "--max-seconds"),
    (["dataset-build", "DS", "--out", "OUT", "--max-residual-px", "nan"], "--max-residual-px"),
    (["dataset-build", "DS", "--out", "OUT", "--min-sharpness", "-1"], "--min-sharpness"),
    (["dataset-build", "DS", "--out", "OUT", "--duplicate-threshold", "inf"], "--duplicate"),
    (["calibrate", "DS", "--board", "x", "--outlier-factor", "nan", "--out", "OUT/c"], "--outlier"),
    (["calibrate", "DS", "--board", "x", "--outlier-factor", "0.5", "--out", "OUT/c"], "--outlier"),
    (["export", "CKPT", "--torchscript", "CKPT"], "checkpoint"),
    (["train-detector", "--out", "OUT", "--synthetic", "2", "--seed", "-1"], "--seed"),
    (["train", "DS", "--out", "CKPT"], "--out"),  # a file, not a folder
    (["restore", "CKPT", "IMGS", "--out", "CKPT"], "--out"),
    (["simulate", "calib_samples/rain.yaml", "--out", "CKPT"], "--out"),
    (["capture-ingest", "DS", "--out", "CKPT"], "--out"),
    (["dataset-build", "DS", "--out", "CKPT"], "--out"),
    (["eval", "CKPT", "--data", "DS", "--out", "CKPT"], "--out"),
    (["tradeoff", "DS", "--out", "CKPT"], "--out"),
    (["train-detector", "--out", "CKPT", "--synthetic", "2"], "--out"),
    (["demo", "--out", "CKPT"], "--out"),
    (["calibrate", "DS", "--board", "x", "--model", "pinhole-radtan", "--out", "DS"], "folder"),
    (["export", "CKPT", "--onnx", "DS"], "folder"),
    (["realism", "--render", "ours", "--seed", "-1"], "--seed"),
    (["simulate", "rain", "--out", "OUT", "--seed", str(2**32)], "--seed"),  # was taken
    (["realism", "--render", "ours", "--json", "DS"], "folder"),
    (["tradeoff", "DS", "--out", "OUT", "--variants", "nope"], "nope"),
    (["eval", "DS", "--latency-runs", "many"], "--latency-runs"),
    (["eval", "CKPT", "--data", "OUT/none"], "--data"),
    (["eval", "CKPT", "--data", "DS", "--calibration", "DS", "--precision", "fp32"], "int8"),
    (["export", "DS", "--onnx", "OUT/m.onnx", "--size", "big"], "--size"),
    (["export", "CKPT", "--onnx", "OUT/model"], "model.onnx"),
    (["demo", "--bogus"], "--bogus"),
    (["restore", "CKPT", "IMGS", "--out", "OUT", "--tile", "-1"], "--tile"),
    (["restore", "CKPT", "IMGS", "--out", "OUT", "--tile", "abc"], "--tile"),
    (["restore", "CKPT", "IMGS", "--out", "OUT", "--tile", "0"], "--tile"),
    (["restore", "CKPT", "IMGS", "--out", "OUT", "--overlap", "-2"], "--overlap"),
    (["restore", "CKPT", "IMGS", "--out", "OUT", "--batch-size", "0"], "--batch-size"),
    (
        ["restore", "CKPT", "IMGS", "--out", "OUT", "--jpeg-quality", "0"],
        "--jpeg-quality: expected",
    ),
    (
        ["restore", "CKPT", "IMGS", "--out", "OUT", "--jpeg-quality", "101"],
        "--jpeg-quality: expected",
    ),
    (
        ["restore", "CKPT", "IMGS", "--out", "OUT", "--jpeg-quality", "abc"],
        "--jpeg-quality: expected",
    ),
    (["restore", "CKPT", "IMGS", "--out", "OUT", "--camera", "cam7"], "--camera"),
    (["restore", "CKPT", "IMGS", "--out", "OUT", "--precision", "fp8"], "--precision"),
    (["restore", "CKPT", "IMGS", "--out", "OUT", "--device", "tpu"], "--device"),
    (["restore", "CKPT", "IMGS"], "--out"),
    (["restore", "CKPT", "OUT/none", "--out", "OUT"], "none"),
    # a detector where a restoration checkpoint is expected, and vice versa
    (["restore", "DET", "IMGS", "--out", "OUT"], "DET.pt"),
    (["restore", "CKPT", "IMGS", "--out", "OUT", "--only-obstructed", "CKPT"], "CKPT.pt"),
    (["restore", "CKPT", "IMGS", "--out", "OUT", "--only-obstructed", "IMGS"], "input"),
    (["detect", "CKPT", "IMGS", "--out", "OUT"], "CKPT.pt"),
    (["detect", "DET", "IMGS", "--out", "OUT", "--threshold", "1.5"], "--threshold"),
    (["detect", "DET", "IMGS", "--out", "OUT", "--threshold", "x"], "--threshold"),
    (["detect", "DET", "IMGS", "--out", "OUT", "--threshold", "1"], "expected a number in (0, 1)"),
    (["detect", "DET", "IMGS", "--out", "OUT", "--batch-size", "0"], "--batch-size"),
    (["detect", "DET", "IMGS", "--out", "OUT", "--sheet-frames", "-1"], "--sheet-frames"),
    (["detect", "DET", "IMGS", "--out", "OUT", "--topics", "a"], "--topics"),
    (["detect", "DET", "IMGS", "--out", "OUT", "--topics", "/a", "/a"], "two different topics"),
    (["restore", "CKPT", "IMGS", "--out", "OUT", "--topics", "/a", "/b", "/c"], "/c"),
    (["capture-ingest", "DS", "--out", "OUT", "--topics", "/a,"], "--topics"),
    (["calibrate", "DS", "--board", "x", "--model", "pinhole-equi", "--topics", "/a"], "--topics"),
    (["detect", "DET", "OUT/none", "--out", "OUT"], "none"),
    (["train-detector", "--out", "OUT"], "training data"),
    (["train-detector", "--out", "OUT", "--synthetic", "-1"], "--synthetic"),
    (["train-detector", "--out", "OUT", "--synthetic", "2", "--steps", "0"], "steps"),
    (["train-detector", "--out", "OUT", "--synthetic", "2", "--batch-size", "0"], "batch"),
    (["train-detector", "--out", "OUT", "--synthetic", "2", "--minutes", "0"], "--minutes"),
    (["train-detector", "--out", "OUT", "--synthetic", "2", "--input-size", "big"], "--input-size"),
    (["train-detector", "--out", "OUT", "--synthetic", "2", "--input-size", "0x9"], "--input-size"),
    (["train-detector", "--out", "OUT", "--synthetic", "2", "--threads", "0"], "threads"),
    (["train-detector", "--out", "OUT", "--set-per-kind", "1"], "--set-per-kind"),
    (
        ["train-detector", "--out", "OUT", "--simulated-set", "OUT/s", "--set-per-kind", "1"],
        "--set-per-kind: expected 2 or more (one recording of each kind is held out)",
    ),
    (
        ["train-detector", "--out", "OUT", "--simulated-set", "OUT/s", "--set-per-kind", "101"],
        "expected at most 100",
    ),
    (
        ["train-detector", "--out", "OUT", "--simulated-set", "OUT/s", "--set-frames", "300000"],
        "over 1000000 frames",
    ),
    (
        ["train-detector", "DS", "--out", "OUT", "--clean-images", "DS"],
        "--clean-images is used only with --synthetic N",
    ),
    (
        ["train-detector", "DS", "--out", "OUT", "--set-frames", "3"],
        "--set-frames is used only with --simulated-set",
    ),
    (["train-detector", "--out", "OUT", "--synthetic", "2", "--hard", "-1"], "--hard"),
    (["train-detector", "--out", "OUT", "--synthetic", "2", "--hard", "5"], "--hard N is made"),
    (["train-detector", "--out", "OUT", "--synthetic", "2", "--workers", "0"], "--workers"),
    (["train-detector", "--out", "OUT", "--synthetic", "2", "--device", "tpu"], "--device"),
    (["capture-ingest", "DS", "--out", "OUT", "--device", "tpu"], "--device"),
    (["realism", "--render", "nope"], "nope"),
    (["realism", "--render", "ours", "--size", "big"], "--size"),
    (["realism", "--render", "ours", "--size", "0x480"], "--size"),
    (["realism", "--render", "ours", "--size", "100000x100000"], "at most 8192x8192"),
    (["realism", "DS", "--split", "nosuch"], "nosuch"),
    (["realism", "DS", "--size", "64x64", "--seed", "3"], "--size, --seed: for rendered drops"),
    (["export", "CKPT", "--torchscript", "OUT/m.onnx"], "would take it for an ONNX model"),
    (["no-such-command"], "no-such-command"),
]


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A valid tiny split dataset, so that the bad file is the only problem."""
    return write_split_dataset(tmp_path_factory.mktemp("errors") / "ds")


@pytest.fixture(scope="module")
def models(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A tiny restoration checkpoint, a tiny untrained detector and a folder of images."""
    from lenspair.model.detection.train import save_detector
    from lenspair.model.networks.detector import AnomalyDetector, DetectorSpec
    from tests.model.train_fixtures import make_checkpoint, write_paired_folder

    root = tmp_path_factory.mktemp("models")
    detector = AnomalyDetector(DetectorSpec(widths=(4, 4, 4), input_size=(32, 48)))
    save_detector(root / "DET.pt", detector)
    return {
        "CKPT": make_checkpoint(root / "CKPT.pt"),
        "DET": root / "DET.pt",
        "IMGS": write_paired_folder(root / "pairs", count=2) / "input",
    }


class _Said(logging.Handler):
    """What the command logs: in a terminal, more lines on stderr before the error."""

    def __init__(self) -> None:
        super().__init__(logging.INFO)
        self.lines: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.lines.append(f"{record.levelname} {record.name}: {record.getMessage()}")


def _run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, list[str]]:
    said, logger = _Said(), logging.getLogger("lenspair")
    level = logger.level
    logger.addHandler(said)
    logger.setLevel(logging.INFO)  # as the CLI logs in a terminal
    try:
        code = main(argv)  # any exception other than SystemExit fails the test with its traceback
    finally:
        logger.removeHandler(said)
        logger.setLevel(level)
    captured = capsys.readouterr()
    # a precision line on stdout, or a log line, before the error: not one line either
    return code, said.lines + captured.out.strip().splitlines() + captured.err.strip().splitlines()


def _expand(
    args: list[str], bad: Path, dataset: Path, out: Path, models: dict[str, Path]
) -> list[str]:
    table = {"BAD": str(bad), "DS": str(dataset), "OUT": str(out)}
    table.update({name: str(path) for name, path in models.items()})
    return [table.get(arg, arg.replace("OUT", str(out))) for arg in args]


def test_every_command_has_bad_input_cases() -> None:
    assert set(FILE_CASES) == set(COMMANDS)
    named = {argv[0] for argv, _ in OPTION_CASES}
    assert set(COMMANDS) <= named


def _file_cases() -> list[tuple[str, list[str], str]]:
    """Every (command, template, kind); an empty --config file is valid (all defaults)."""
    return [
        (name, args, kind)
        for name, cases in FILE_CASES.items()
        for args in cases
        for kind in sorted(BAD_FILES)
        if not (kind == "empty" and "--config" in args)
    ]


@pytest.mark.parametrize(
    "command,template,kind",
    _file_cases(),
    ids=lambda value: value if isinstance(value, str) else "-".join(value)[:40],
)
def test_bad_file_gives_one_line_naming_it(
    command: str,
    template: list[str],
    kind: str,
    dataset: Path,
    models: dict[str, Path],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    bad = tmp_path / f"bad-{kind}.yaml"
    BAD_FILES[kind](bad)
    argv = [command, *_expand(template, bad, dataset, tmp_path / "out", models)]
    try:
        code, lines = _run(argv, capsys)
    except SystemExit as exc:
        code, lines = int(exc.code or 0), capsys.readouterr().err.strip().splitlines()
    assert code == 2, (argv, lines)
    assert len(lines) == 1, (argv, lines)
    assert bad.name in lines[0], (argv, lines)
    assert "Traceback" not in lines[0]


@pytest.mark.parametrize("argv,token", OPTION_CASES, ids=lambda v: "-".join(v)[:50])
def test_bad_option_gives_one_line_naming_it(
    argv: list[str],
    token: str,
    dataset: Path,
    models: dict[str, Path],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    argv = _expand(argv, tmp_path / "unused", dataset, tmp_path / "out", models)
    try:
        code, lines = _run(argv, capsys)
    except SystemExit as exc:
        code, lines = int(exc.code or 0), capsys.readouterr().err.strip().splitlines()
    assert code == 2, (argv, lines)
    assert len(lines) == 1, (argv, lines)
    assert token in lines[0], (argv, lines)


@settings(max_examples=25, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    text=st.one_of(
        st.text(alphabet="ab:-[]{}!&*|>'\" \n\t#%@`,?", max_size=40),
        st.recursive(
            st.none() | st.booleans() | st.integers() | st.text(max_size=5),
            lambda inner: (
                st.lists(inner, max_size=3)
                | st.dictionaries(
                    st.sampled_from(["rig", "recording", "seed", "x"]), inner, max_size=3
                )
            ),
            max_leaves=8,
        ).map(yaml.safe_dump),
    )
)
def test_malformed_scene_yaml_gives_one_line(
    text: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    scene = tmp_path / "scene.yaml"
    scene.write_text(text)
    out = tmp_path / "never"
    code, lines = _run(["simulate", str(scene), "--out", str(out)], capsys)
    assert code == 2
    assert len(lines) == 1 and "scene.yaml" in lines[0], lines


@pytest.mark.parametrize("content", [b"", b"\x08\x07garbage not protobuf", b"ir_version: 7\n"])
def test_bad_onnx_model_gives_one_line_naming_it(
    content: bytes, models: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """An .onnx MODEL goes to ONNX Runtime, whose errors are many lines long."""
    model = tmp_path / "broken.onnx"
    model.write_bytes(content)
    argv = ["restore", str(model), str(models["IMGS"]), "--out", str(tmp_path / "out")]
    code, lines = _run([*argv, "--device", "cpu"], capsys)
    assert code == 2, lines
    assert len(lines) == 1 and "broken.onnx" in lines[0], lines


def test_a_file_system_refusal_is_one_line_naming_the_path(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "out"
    out.mkdir()
    (out / "rain").write_text("not a folder")  # where the recording's folder goes
    recording = tmp_path / "rain"
    assert main(["simulate", "rain", "--out", str(recording), "--frames", "2"]) == 0
    capsys.readouterr()
    code = main(["capture-ingest", str(recording), "--out", str(out)])
    lines = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and len(lines) == 1, lines
    assert str(out / "rain") in lines[0]


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs Linux's /proc")
def test_an_out_folder_that_cannot_be_made_there_is_one_line_naming_it(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """/proc refuses new folders with ENOENT, not a permission error: still one line, exit 2."""
    out = Path("/proc") / f"lenspair-test-{os.getpid()}" / "rec"
    code = main(["simulate", "rain", "--out", str(out), "--frames", "1"])
    lines = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(lines) == 1, lines
    assert str(out.parent) in lines[0] and "No such file or directory" in lines[0]


@pytest.mark.parametrize("where", ["before", "after"])
def test_verbose_shows_the_refusal_s_traceback_before_or_after_the_command(
    tmp_path: Path, where: str
) -> None:
    """``-v`` is taken where users type it, also after the command, and is not reset there."""
    out = tmp_path / "out"
    out.mkdir()
    (out / "rain").write_text("not a folder")  # a file where the recording's folder goes
    recording = tmp_path / "rain"
    assert main(["simulate", "rain", "--out", str(recording), "--frames", "2"]) == 0
    argv = ["capture-ingest", str(recording), "--out", str(out)]
    argv = ["-v", *argv] if where == "before" else [*argv, "-v"]
    with pytest.raises(OSError):  # the traceback a bug report wants, not the one line
        main(argv)


@pytest.mark.parametrize(
    "argv",
    [
        ["restore", "--topics", "/a", "/b", "model.pt", "rec.bag", "--out", "o"],
        ["restore", "--topics", "/a,/b", "model.pt", "rec.bag", "--out", "o"],
        ["restore", "model.pt", "rec.bag", "--out", "o", "--topics=/a,/b"],
        ["detect", "--topics", "/a", "/b", "det.pt", "rec.bag"],
        ["capture-ingest", "--topics", "/a,/b", "rec.bag", "--out", "o"],
        [
            "calibrate",
            "--topics",
            "/a",
            "/b",
            "rec.bag",
            "--board",
            "b",
            "--model",
            "pinhole-equi",
            "--out",
            "c",
        ],
    ],
)
def test_topics_before_the_positionals_take_two_words(argv: list[str]) -> None:
    # "one or more" words swallowed the recording after them
    args = build_parser(argv[0]).parse_args(expand_topics(argv))
    assert args.topics == ("/a", "/b")
    positional = {"restore": "input", "detect": "input", "capture-ingest": "recording"}
    name = positional.get(argv[0], "recording")
    assert str(getattr(args, name)) == "rec.bag"


def test_a_quoted_library_error_is_its_first_line_without_terminal_colours() -> None:
    # torch.export's message, as eval --precision int8 wrote it into metrics.md
    coloured = RuntimeError(
        "Failed to export the model with torch.export. \x1b[96mThis is step 1/3\x1b[0m of ...\n"
        "more lines"
    )
    assert (
        first_line(coloured)
        == "Failed to export the model with torch.export. This is step 1/3 of ..."
    )
    assert first_line(ValueError()) == "ValueError"


def test_a_quoted_library_message_skips_leading_blank_lines_and_says_when_empty() -> None:
    # OpenImageIO's geterror() can start with a blank line, or be empty
    assert first_text_line("\n  \nPNG read error: bad CRC\nsecond") == "PNG read error: bad CRC"
    assert first_text_line("", "unknown error") == "unknown error"
    assert first_text_line(" \n") == ""


def test_a_seed_too_large_for_training_is_refused_at_the_option_and_in_a_config(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # torch.manual_seed raised "Overflow when unpacking long long" as a traceback,
    # or after setup, from the per-epoch seed train.seed * 100_003 + epoch
    from lenspair.cli import main
    from lenspair.model.training.config import TrainConfig

    too_large = str(2**32)
    with pytest.raises(SystemExit) as stop:  # argparse's own exit
        main(["train", str(tmp_path), "--out", str(tmp_path / "r"), "--seed", too_large])
    assert stop.value.code == 2
    assert "argument --seed: expected an integer 0 .. 4294967295" in capsys.readouterr().err
    config = tmp_path / "c.yaml"
    config.write_text(f"train: {{seed: {too_large}}}\n")
    argv = ["train", str(tmp_path), "--out", str(tmp_path / "r"), "--config", str(config)]
    assert main(argv) == 2
    assert f"train.seed: expected 0 .. 4294967295, got {too_large}" in capsys.readouterr().err
    assert TrainConfig(seed=2**32 - 1).seed * 100_003 + 10**6 < 2**63  # the largest still fits


def test_a_split_given_with_no_dataset_root_is_refused(
    dataset: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """realism measured a paired folder whole and ignored --split, even one not there."""
    code, lines = _run(["realism", str(dataset / "test"), "--split", "nosuch"], capsys)
    assert code == 2 and len(lines) == 1 and "no dataset root given" in lines[0]

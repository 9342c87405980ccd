"""WIDTHxHEIGHT sizes: one parser for every option, width first in and in its errors."""

import pytest

from lenspair.cli import main
from lenspair.core.sizes import parse_size


def test_sizes_are_width_first_and_bounded() -> None:
    assert parse_size("540x360") == (540, 360)
    assert parse_size(" 64X48 ") == (64, 48)
    for text, message in [
        ("540", "expected WIDTHxHEIGHT such as 540x360, got '540'"),
        ("ax3", "expected WIDTHxHEIGHT"),
        ("-4x3", "expected WIDTHxHEIGHT"),
        ("0x360", "expected at least 1x1, got '0x360'"),
    ]:
        with pytest.raises(ValueError, match=message):
            parse_size(text)
    with pytest.raises(ValueError, match="expected at least 8x8, got '7x5'"):
        parse_size("7x5", minimum=8)  # as typed: it said "got (5, 7)", height first
    with pytest.raises(ValueError, match="at most 100x100, got '101x50'"):
        parse_size("101x50", maximum=100)


@pytest.mark.parametrize(
    ("argv", "token"),
    [
        (["train-detector", "--synthetic", "2", "--input-size", "7x5"], "at least 8x8, got '7x5'"),
        (["train-detector", "--synthetic", "2", "--input-size", "abc"], "such as 540x360"),
        (["export", "ck.pt", "--onnx", "m.onnx", "--size", "4x4"], "at least 8x8"),
        (["realism", "--render", "sharp", "--size", "9000x100"], "at most 8192x8192"),
        (["capture-ingest", "rec", "--out", "o", "--size", "540"], "WIDTHxHEIGHT"),
    ],
)
def test_every_size_option_says_its_name_and_the_size_as_typed(
    argv: list[str], token: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    (line,) = [line for line in capsys.readouterr().err.splitlines() if "error" in line]
    assert exit_.value.code == 2 and token in line and "--" in line and "int()" not in line


def test_the_commands_minimum_sides_are_the_networks() -> None:
    """Written out in the commands (importing them would load torch for --help)."""
    from lenspair.commands import export, train_detector
    from lenspair.model.networks.detector import MAX_INPUT_SIDE, TILE_STRIDE
    from lenspair.model.networks.padding import MIN_SIDE

    assert train_detector.MIN_INPUT_SIDE == TILE_STRIDE
    assert train_detector.MAX_INPUT_SIDE == MAX_INPUT_SIDE
    assert export.MIN_INPUT_SIDE == MIN_SIDE

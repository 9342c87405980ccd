from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from lenspair.core.durations import minutes, seconds, steps_or_seconds


@pytest.mark.parametrize(
    ("text", "expected"),
    [("90", 90.0), ("90s", 90.0), ("10m", 600.0), ("1h", 3600.0), (".5", 0.5), ("1e3", 1000.0)],
)
def test_a_time_reads_as_python_writes_numbers(text: str, expected: float) -> None:
    # '1e3' and '.5' were taken by --max-seconds before it took units
    assert seconds(text) == expected


@pytest.mark.parametrize("text", ["0", "-5", "inf", "nan", "5x", "", "m"])
def test_what_is_no_positive_time_is_refused(text: str) -> None:
    with pytest.raises(ValueError, match="expected a positive time"):
        seconds(text)


@given(st.integers(1, 10**9))
def test_a_whole_number_is_steps_and_with_a_unit_a_time(count: int) -> None:
    assert steps_or_seconds(str(count)) == (count, None)
    assert steps_or_seconds(f"{count}m") == (None, count * 60.0)
    with pytest.raises(ValueError, match="whole number"):
        steps_or_seconds(f"{count}.5")


@pytest.mark.parametrize("text", ["1e400", "1e400s", "1e308h", "3e306m"])
def test_a_number_too_large_to_be_finite_is_refused(text: str) -> None:
    # float() reads 1e400 as inf; recorded as max_seconds: .inf, it made the run's
    # checkpoint unreadable to eval and --resume
    with pytest.raises(ValueError, match="too large"):
        seconds(text)
    with pytest.raises(ValueError, match="too large"):
        steps_or_seconds(text)


@pytest.mark.parametrize(
    "option",
    [["--max-seconds", "1e400"], ["--checkpoint-every", "1e400"], ["--checkpoint-every", "1e400s"]],
)
def test_train_refuses_a_duration_too_large_in_one_line(
    tmp_path: Path, option: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    # --checkpoint-every 1e400 ended in an OverflowError traceback, exit 1
    from lenspair.cli import main

    with pytest.raises(SystemExit) as exit_:
        main(["train", str(tmp_path / "ds"), "--out", str(tmp_path / "run"), *option])
    (line,) = [line for line in capsys.readouterr().err.splitlines() if "error" in line]
    assert exit_.value.code == 2 and f"argument {option[0]}: too large" in line
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize(
    ("text", "expected"), [("4", 4.0), ("2.5", 2.5), ("5m", 5.0), ("90s", 1.5), ("1H", 60.0)]
)
def test_minutes_read_a_bare_number_as_minutes_and_a_unit_as_said(
    text: str, expected: float
) -> None:
    assert minutes(text) == pytest.approx(expected)


@pytest.mark.parametrize("text", ["0", "-1", "5 min", "m", "1e400"])
def test_minutes_refuse_what_is_not_a_positive_time(text: str) -> None:
    with pytest.raises(ValueError):
        minutes(text)


def test_a_refused_minutes_quotes_what_was_typed() -> None:
    # it quoted '0m', which nobody typed, in the seconds' wording
    with pytest.raises(ValueError, match=r"positive time in minutes like 4, .*; got '0'$"):
        minutes("0")

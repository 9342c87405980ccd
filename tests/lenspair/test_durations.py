import pytest
from hypothesis import given
from hypothesis import strategies as st

from lenspair.core.durations import seconds, steps_or_seconds


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

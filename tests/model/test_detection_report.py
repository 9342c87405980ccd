"""The contact-sheet sample of ``lenspair detect``: bounded and spread over the input."""

from lenspair.model.detection.report import SpreadSample


def test_spread_sample_is_bounded_and_spans_the_stream() -> None:
    for length in (0, 1, 5, 12, 13, 100, 1000):
        sample: SpreadSample[int] = SpreadSample(12)
        for index in range(length):
            if sample.wants(index):
                sample.add(index, index)
            assert len(sample.kept) <= 24  # memory: never more than 2 * size
        picks = sample.picks()
        assert len(picks) == min(12, length) and picks == sorted(set(picks))
        if length:
            assert picks[0] == 0 and picks[-1] >= (length - 1) // 2
        if length <= 12:
            assert picks == list(range(length))


def test_spread_sample_of_size_zero_keeps_nothing() -> None:
    sample: SpreadSample[int] = SpreadSample(0)
    for index in range(10):
        sample.add(index, index)
    assert not sample.wants(0) and sample.picks() == []

"""bench_detector times GEA as everything else times it: channels-last, as deployed."""

import pytest
import torch
from torch import nn

from benchmarks import bench_detector


def test_gea_is_timed_channels_last(monkeypatch: pytest.MonkeyPatch) -> None:
    # it timed GEA in NCHW while eval, restore and bench_model time it channels-last
    layouts: list[bool] = []

    class Network(nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.first = nn.Conv2d(1, 4, 3, padding=1)
            self.second = nn.Conv2d(4, 4, 3, padding=1)

        def forward(self, x: torch.Tensor) -> torch.Tensor:
            # a mono frame is laid out alike either way; four channels tell the layouts apart
            features = self.first(x)
            layouts.append(
                features.is_contiguous(memory_format=torch.channels_last)
                and self.second.weight.is_contiguous(memory_format=torch.channels_last)
            )
            return self.second(features)  # type: ignore[no-any-return]

    monkeypatch.setattr(bench_detector, "build_model", lambda variant, channels: Network())
    threads = torch.get_num_threads()
    try:
        result = bench_detector.run(runs=1, threads=1)
    finally:
        torch.set_num_threads(threads)
    timed = layouts[:4]  # 3 warm-up passes and 1 timed one, before the FLOP count
    assert len(timed) == 4 and all(timed)
    assert result["gea_layout"] == "channels-last"

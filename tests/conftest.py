"""Shared test settings: quiet progress bars, headless plotting, fast hypothesis, own caches."""

import os
from collections.abc import Iterator

os.environ.setdefault("LENSPAIR_QUIET", "1")
os.environ.setdefault("MPLBACKEND", "Agg")

import pytest
from hypothesis import settings

settings.register_profile("ci", max_examples=40, deadline=None, derandomize=True)
settings.load_profile("ci")


@pytest.fixture(autouse=True)
def _own_measurement_cache(tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    """Each test its own dataset-build cache: none reads what another measured, nor ~/.cache."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("LENSPAIR_CACHE_DIR", str(tmp_path_factory.mktemp("cache")))
        yield

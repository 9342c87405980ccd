"""Fixtures of the dataset tests: synthetic ingested recordings."""

from pathlib import Path

import pytest

from tests.dataset.dataset_synth import RecordingFactory, make_recording


@pytest.fixture
def recording(tmp_path: Path) -> RecordingFactory:
    """``recording(rid, **options)`` writes a synthetic ingested recording under tmp/ingested."""

    def factory(rid: str, **options: object) -> Path:
        return make_recording(tmp_path / "ingested", rid, **options)  # type: ignore[arg-type]

    return factory

"""Stand-ins for the demo's stage tests: a fake ``lenspair`` command and three stages."""

from pathlib import Path

from lenspair.demo_stages import Stage


class FakeCli:
    """Stands in for ``lenspair.cli.main``: writes the stage's output, records the call."""

    def __init__(self, outputs: dict[str, Path]) -> None:
        self.outputs = outputs
        self.calls: list[str] = []

    def __call__(self, argv: list[str]) -> int:
        name = argv[0]
        self.calls.append(name)
        self.outputs[name].mkdir(parents=True, exist_ok=True)
        (self.outputs[name] / "done").write_text(" ".join(argv))
        return 0


def three_stages(out: Path, spec: Path) -> list[Stage]:
    """simulate ``spec`` -> ingest (resumable) -> train, writing under ``out``."""
    return [
        Stage("simulate", ("simulate", str(spec)), out / "rec"),
        Stage("ingest", ("ingest", str(out / "rec")), out / "ing", resumable=True),
        Stage("train", ("train", str(out / "ing")), out / "run"),
    ]

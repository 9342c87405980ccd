"""``python -m benchmarks`` hands every benchmark ``--out DIR``, and one failure stops none."""

import importlib
import pkgutil
from pathlib import Path

import pytest
import torch

import benchmarks
from benchmarks.__main__ import main

NAMES = sorted(
    m.name for m in pkgutil.iter_modules(benchmarks.__path__) if m.name.startswith("bench_")
)


@pytest.mark.parametrize("name", NAMES)
def test_every_benchmark_takes_the_runners_out_option(
    name: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # An option nobody knows makes argparse stop before any measuring; its
    # message then lists every unknown option, --out among them if it were one.
    module = importlib.import_module(f"benchmarks.{name}")
    with pytest.raises(SystemExit) as stop:
        module.main(["--out", str(tmp_path), "--no-such-option"])
    assert stop.value.code == 2
    error = capsys.readouterr().err
    assert "unrecognized arguments: --no-such-option" in error
    assert "--out" not in error.split("unrecognized arguments:")[1]


def test_a_benchmark_that_exits_is_a_failure_and_the_rest_still_run(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    ran = []

    class Stub:
        def __init__(self, name: str) -> None:
            self.name = name

        def main(self, argv: list[str]) -> int:
            ran.append(self.name)
            if self.name == "bench_effects":
                raise SystemExit(2)  # what argparse does on an unknown option
            if self.name == "bench_int8":
                raise RuntimeError("out of memory")  # stopped every later benchmark
            return 0

    monkeypatch.setattr(importlib, "import_module", lambda dotted: Stub(dotted.split(".")[-1]))
    assert main(["--only", "effects", "int8", "ingest"]) == 1
    assert ran == ["bench_effects", "bench_ingest", "bench_int8"]  # in name order
    error = capsys.readouterr().err
    assert "failed: bench_effects, bench_int8" in error and "out of memory" in error


@pytest.mark.parametrize(
    "argv,said",
    [
        (["--only", "nosuch"], "no benchmark named nosuch; choose from"),  # ran nothing, rc 0
        (["--only"], "expected at least one argument"),  # ran every benchmark
    ],
)
def test_only_names_benchmarks_that_exist(
    argv: list[str], said: str, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr(importlib, "import_module", lambda dotted: pytest.fail("ran " + dotted))
    with pytest.raises(SystemExit) as stop:
        main(argv)
    assert stop.value.code == 2 and said in capsys.readouterr().err


def test_an_out_that_is_a_file_is_refused_before_any_work(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr(importlib, "import_module", lambda dotted: pytest.fail("ran " + dotted))
    (tmp_path / "results").write_text("")
    with pytest.raises(SystemExit):
        main(["--out", str(tmp_path / "results"), "--only", "effects"])
    assert "exists and is not a folder" in capsys.readouterr().err


def test_a_benchmark_that_sets_the_thread_count_does_not_set_the_next_ones(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    calls: list[int] = []

    class Stub:
        def main(self, argv: list[str]) -> int:
            torch.set_num_threads(1)  # as bench_detector does by default
            return 0

    monkeypatch.setattr(torch, "get_num_threads", lambda: 3)  # the machine's count
    monkeypatch.setattr(torch, "set_num_threads", calls.append)
    monkeypatch.setattr(importlib, "import_module", lambda dotted: Stub())
    assert main(["--only", "detector", "effects"]) == 0
    # before each benchmark the runner sets the machine's count back; each stub then sets 1
    assert calls == [3, 1, 3, 1]


@pytest.mark.parametrize(
    "name,option",
    [("bench_dataset", "--runs"), ("bench_dataset", "--pairs"), ("bench_model", "--runs")],
)
def test_counts_below_one_are_refused_before_measuring(
    name: str, option: str, capsys: pytest.CaptureFixture[str]
) -> None:
    # --runs 0 ended in a StatisticsError traceback; --pairs 0 printed meaningless ratios
    module = importlib.import_module(f"benchmarks.{name}")
    with pytest.raises(SystemExit) as stop:
        module.main([option, "0"])
    assert stop.value.code == 2 and "expected a positive integer" in capsys.readouterr().err

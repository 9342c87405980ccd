"""``python -m benchmarks`` runs each benchmark in its own process, hands it ``--out DIR``,
stamps what it writes with the run's id, and one failure stops none."""

import importlib
import json
import os
import pkgutil
import subprocess
import sys
from pathlib import Path

import pytest

import benchmarks
from benchmarks import RUN_KEY
from benchmarks import __main__ as runner
from benchmarks.__main__ import main

NAMES = sorted(
    m.name for m in pkgutil.iter_modules(benchmarks.__path__) if m.name.startswith("bench_")
)


@pytest.fixture(autouse=True)
def quiet_cpu(monkeypatch: pytest.MonkeyPatch) -> None:
    """The runner reads a quiet CPU's pressure, whatever else this machine runs meanwhile."""
    monkeypatch.setattr(runner, "cpu_pressure", lambda: "some avg10=0.00 avg60=0.00")


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


def _stubs(monkeypatch: pytest.MonkeyPatch, scripts: dict[str, str]) -> list[str]:
    """Run ``scripts[name]`` (Python source) in place of each benchmark; returns the names run."""
    ran: list[str] = []

    def command(name: str, out: Path | None) -> list[str]:
        ran.append(name)
        return [sys.executable, "-c", scripts.get(name, ""), str(out)]

    monkeypatch.setattr(runner, "command", command)
    return ran


def test_a_benchmark_that_exits_is_a_failure_and_the_rest_still_run(
    monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]
) -> None:
    ran = _stubs(
        monkeypatch,
        {
            "bench_effects": "raise SystemExit(2)",  # what argparse does on an unknown option
            "bench_int8": "raise RuntimeError('out of memory')",  # stopped every later one
        },
    )
    assert main(["--only", "effects", "int8", "ingest"]) == 1
    assert ran == ["bench_effects", "bench_ingest", "bench_int8"]  # in name order
    error = capfd.readouterr().err
    assert "failed: bench_effects, bench_int8" in error and "out of memory" in error


def test_each_benchmark_runs_in_a_process_of_its_own(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # bench_detector tuned the process-wide allocator, and bench_model's "default
    # malloc" column then timed the tuned one: nothing may carry over between them
    record = "import os, sys; open(sys.argv[1] + '/pids', 'a').write(f'{os.getpid()}\\n')"
    _stubs(monkeypatch, {"bench_detector": record, "bench_model": record})
    assert main(["--out", str(tmp_path), "--only", "detector", "model"]) == 0
    pids = (tmp_path / "pids").read_text().split()
    assert len(pids) == 2 and len(set(pids)) == 2 and str(os.getpid()) not in pids


def test_the_command_runs_the_benchmark_module_from_any_folder(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    assert runner.command("bench_model", tmp_path) == [
        sys.executable, "-m", "benchmarks.bench_model", "--out", str(tmp_path)
    ]  # fmt: skip
    monkeypatch.chdir(tmp_path)  # not the repository: benchmarks is found all the same
    help_run = [*runner.command("bench_effects", None), "--help"]
    done = subprocess.run(help_run, env=runner._environment(), capture_output=True, text=True)
    assert done.returncode == 0 and "effects.md and effects.json" in done.stdout


def test_every_json_a_benchmark_writes_carries_the_run_id_and_the_machine(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    (tmp_path / "older.json").write_text('{"from": "an earlier run"}\n')
    write = "import json, sys; open(sys.argv[1] + '/{}.json', 'w').write(json.dumps({{'x': 1}}))"
    _stubs(monkeypatch, {"bench_int8": write.format("int8"), "bench_model": write.format("model")})
    assert main(["--out", str(tmp_path), "--only", "int8", "model"]) == 0
    int8, model, older = (
        json.loads((tmp_path / f"{n}.json").read_text()) for n in ("int8", "model", "older")
    )
    assert int8["x"] == 1 and int8[RUN_KEY] == model[RUN_KEY]  # one run id for the whole run
    machine = int8[RUN_KEY]
    assert machine["id"] and machine["cores"] == os.cpu_count() and machine["threads"] >= 1
    assert {"cpu", "onednn_max_cpu_isa", "started"} <= set(machine)
    assert RUN_KEY not in older  # not written in this run: not claimed for it
    # a second run has another id
    assert main(["--out", str(tmp_path), "--only", "model"]) == 0
    assert json.loads((tmp_path / "model.json").read_text())[RUN_KEY]["id"] != machine["id"]


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
    monkeypatch.setattr(runner, "command", lambda name, out: pytest.fail("ran " + name))
    with pytest.raises(SystemExit) as stop:
        main(argv)
    assert stop.value.code == 2 and said in capsys.readouterr().err


def test_an_out_that_is_a_file_is_refused_before_any_work(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr(runner, "command", lambda name, out: pytest.fail("ran " + name))
    (tmp_path / "results").write_text("")
    with pytest.raises(SystemExit):
        main(["--out", str(tmp_path / "results"), "--only", "effects"])
    assert "exists and is not a folder" in capsys.readouterr().err


@pytest.mark.parametrize(
    "name,option",
    [
        ("bench_dataset", "--runs"),
        ("bench_dataset", "--pairs"),
        ("bench_model", "--runs"),
        ("bench_calibration", "--repeats"),  # ended in a NameError after rendering every view
        ("bench_calibration", "--views"),
    ],
)
def test_counts_below_one_are_refused_before_measuring(
    name: str, option: str, capsys: pytest.CaptureFixture[str]
) -> None:
    # --runs 0 ended in a StatisticsError traceback; --pairs 0 printed meaningless ratios
    module = importlib.import_module(f"benchmarks.{name}")
    with pytest.raises(SystemExit) as stop:
        module.main([option, "0"])
    assert stop.value.code == 2 and "expected a positive integer" in capsys.readouterr().err


@pytest.mark.parametrize(
    "name,files", [("bench_dataset", "dataset.md and dataset.json"),
                   ("bench_effects", "effects.md and effects.json")]
)  # fmt: skip
def test_help_names_the_files_the_benchmark_writes(
    name: str, files: str, capsys: pytest.CaptureFixture[str]
) -> None:
    # --help said bench_dataset.{md,json}; the files are dataset.md and dataset.json
    module = importlib.import_module(f"benchmarks.{name}")
    with pytest.raises(SystemExit) as stop:
        module.main(["--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    assert stop.value.code == 0 and files in help_text and "bench_" not in help_text


def test_a_benchmark_that_starts_on_a_busy_cpu_is_recorded_and_said(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]
) -> None:
    # at load 8 from other processes fp32 GEA read 2.6x its roofline and int8 13x faster
    # than fp32 (quiet: 1.5x and 0.8x), and nothing in the run said so
    write = "import json, sys; open(sys.argv[1] + '/{}.json', 'w').write(json.dumps({{'x': 1}}))"
    _stubs(monkeypatch, {"bench_int8": write.format("int8"), "bench_model": write.format("model")})
    lines = iter(["some avg10=3.10 avg60=2.00 avg300=1.00 total=1", "some avg10=45.00 avg60=9"])
    monkeypatch.setattr(runner, "cpu_pressure", lambda: next(lines))
    assert main(["--out", str(tmp_path), "--only", "int8", "model"]) == 0
    int8, model = (json.loads((tmp_path / f"{n}.json").read_text()) for n in ("int8", "model"))
    assert "busy_at_start" not in int8[RUN_KEY]  # quiet when it started
    assert model[RUN_KEY]["busy_at_start"] == {"bench_model": 45.0}
    output = capfd.readouterr()
    assert "warning: bench_model starts on a busy CPU (pressure 45 %)" in output.out
    assert "bench_model started with other processes keeping the CPU busy" in output.err

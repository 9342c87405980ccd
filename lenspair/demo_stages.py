"""Running the demo's stages: each reused when finished with the same inputs, else run again.

A stage is one ``lenspair`` subcommand (:class:`Stage`). Once it finishes, a
marker in ``OUT/.stages/<name>.json`` records its arguments, the hashes of the
YAML files it read and, for stages that train or time networks, the CPU's
native precisions; a rerun reuses the stage only when all three match
(:func:`run_stage`). Once one stage runs, every later one runs too
(:func:`run_stages`): they read what it wrote.
"""

import json
import logging
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lenspair.cli import INTERRUPTED, TERMINATED, Terminated
from lenspair.core.fsutil import atomic_write_json, remove_path, sha256_file
from lenspair.errors import DemoError

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Stage:
    """One subcommand invocation and the folder or file it produces.

    Attributes:
        name: the stage's name (its marker is ``OUT/.stages/<name>.json``).
        argv: the subcommand and its arguments, as typed.
        output: the folder or file it writes.
        resumable: the subcommand resumes its own unfinished work, so a
            rerun keeps ``output`` (unless what the stage reads changed).
    """

    name: str
    argv: tuple[str, ...]
    output: Path
    resumable: bool = False


def _marker(out: Path, stage: Stage) -> Path:
    return out / ".stages" / f"{stage.name}.json"


PRECISION_STAGES = ("train", "eval", "tradeoff", "export", "restore", "train-detector", "detect")
"""Commands whose results depend on the precisions the machine runs natively."""


def _fingerprint(stage: Stage) -> dict[str, str]:
    """sha256 of the YAML files a stage reads (scene specs, configs), by path.

    Stages that train or time networks also record the CPU's native
    precisions: the same demo rerun on a CPU without native bf16 (or under
    ``ONEDNN_MAX_CPU_ISA``) trains at fp32 and must not reuse bf16 results.
    """
    inputs = {
        arg: sha256_file(Path(arg))
        for arg in stage.argv
        if arg.endswith(".yaml") and Path(arg).is_file()
    }
    if stage.argv and stage.argv[0] in PRECISION_STAGES:
        # here, not at the top: torch loads only when a stage that needs it runs
        import torch

        # (the same reason: the precision module loads torch)
        from lenspair.model.precision import native_precisions, probe_hardware

        native = native_precisions(probe_hardware(torch.device("cpu")))
        inputs["cpu native precisions"] = ",".join(native)
    return inputs


def run_stage(
    out: Path,
    stage: Stage,
    cli_main: Callable[[list[str]], int],
    reuse: bool = True,
    later: Sequence[Stage] = (),
) -> tuple[float, bool]:
    """Run one stage unless ``reuse`` and a finished marker with the same arguments and inputs.

    Inputs are the YAML files named in the arguments: editing a sample scene
    makes its stages run again. Before a stage runs, its marker and those of
    the ``later`` stages (which read what it writes) are removed: a demo
    killed while it ran, or before they ran again, left an earlier run's
    markers beside a partial or stale output, and the rerun reused them.

    Returns:
        (seconds spent, whether the stage was reused).
    """
    marker = _marker(out, stage)
    if reuse and marker.is_file() and stage.output.exists():
        recorded = _read_marker(marker)
        same_inputs = recorded.get("inputs", {}) == _fingerprint(stage)
        if recorded.get("argv") == list(stage.argv) and same_inputs:
            return float(recorded.get("seconds", 0.0)), True
    for stale in (stage, *later):
        _marker(out, stale).unlink(missing_ok=True)
    # the earlier report described outputs this stage now replaces: a stopped rerun
    # left it beside them, every stage still marked reused
    for name in REPORT_FILES:
        (out / name).unlink(missing_ok=True)
    # A resumable stage picks up where it stopped, unless what it read changed.
    if stage.output.exists() and not (stage.resumable and reuse):
        remove_path(stage.output)
    print(f"\n[{stage.name}] lenspair {' '.join(stage.argv)}", file=sys.stderr, flush=True)
    start = time.perf_counter()
    code = cli_main(list(stage.argv))
    seconds = time.perf_counter() - start
    if code == INTERRUPTED:  # Ctrl-C in the stage: the demo was stopped, nothing failed
        raise KeyboardInterrupt
    if code == TERMINATED:  # SIGTERM, likewise
        raise Terminated
    if code != 0:
        raise DemoError(f"stage {stage.name} failed (exit code {code}); rerun to resume")
    record = {"argv": list(stage.argv), "inputs": _fingerprint(stage), "seconds": round(seconds, 2)}
    atomic_write_json(marker, record)
    return seconds, False


def _read_marker(marker: Path) -> dict[str, Any]:
    """A stage's finished marker; a damaged one (a full disk, an edit) reads as none."""
    try:
        recorded = json.loads(marker.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return recorded if isinstance(recorded, dict) else {}


REPORT_FILES = ("report.md", "report.html", "timings.json")
"""What :func:`run_demo` writes once every stage has run: removed when one runs again."""


def run_stages(
    out: Path, stages: list[Stage], cli_main: Callable[[list[str]], int]
) -> dict[str, dict[str, float | bool]]:
    """Run ``stages`` in order; once one runs, every later one runs too (its inputs changed).

    Returns:
        stage name -> ``{"seconds": ..., "reused": ...}``.
    """
    timings: dict[str, dict[str, float | bool]] = {}
    reuse = True
    for index, stage in enumerate(stages):
        seconds, reused = run_stage(out, stage, cli_main, reuse, stages[index + 1 :])
        reuse = reuse and reused
        timings[stage.name] = {"seconds": round(seconds, 2), "reused": reused}
        log.info("%s: %s (%.1f s)", stage.name, "reused" if reused else "done", seconds)
    return timings

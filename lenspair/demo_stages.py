"""Running the demo's stages: each reused when finished with the same inputs, else run again.

A stage is one ``lenspair`` subcommand (:class:`Stage`). Once it finishes, a
marker in ``OUT/.stages/<name>.json`` records its arguments, the hashes of the
YAML files it read, a digest of its output (:func:`output_digest`) and, for
stages that train or time networks, the CPU's native precisions; a rerun
reuses the stage only when all of them match (:func:`run_stage`). Once one
stage runs, every later one runs too (:func:`run_stages`): they read what it
wrote.
"""

import hashlib
import json
import logging
import os
import shlex
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
        resume_argv: the command that continues an unfinished run of this
            stage (``train ... --resume``); empty: none does.
        resume_file: what an unfinished run left to continue from (its
            ``last.pt``); ``resume_argv`` runs only when it exists.
    """

    name: str
    argv: tuple[str, ...]
    output: Path
    resumable: bool = False
    resume_argv: tuple[str, ...] = ()
    resume_file: Path | None = None


def _marker(out: Path, stage: Stage) -> Path:
    return out / ".stages" / f"{stage.name}.json"


def _started(out: Path, stage: Stage) -> Path:
    """The record of a stage that started and has not finished: what it ran with."""
    return out / ".stages" / f"{stage.name}.started.json"


PRECISION_STAGES = ("train", "eval", "tradeoff", "export", "restore", "train-detector", "detect")
"""Commands whose results depend on the precisions the machine runs natively."""


def _fingerprint(stage: Stage) -> dict[str, str]:
    """sha256 of the YAML files a stage reads (scene specs, configs), by path.

    Stages that train or time networks also record the CPU's native
    precisions and the one ``auto`` trains at: the same demo rerun on a CPU
    without native bf16, or with one slower than fp32 (or under
    ``ONEDNN_MAX_CPU_ISA``), trains at fp32 and must not reuse bf16 results.
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
        from lenspair.model.precision import choose_precision

        decision = choose_precision("auto", torch.device("cpu"), "train")
        inputs["cpu native precisions"] = ",".join(decision.native)
        # a native bf16 that measured slower than fp32 trains at fp32 (measured once per process)
        inputs["cpu auto training precision"] = decision.precision
    return inputs


def output_digest(output: Path) -> str:
    """sha256 over the relative path, size and mtime_ns of every file under ``output``.

    Cheap (no file is read), so reusing an untouched demo stays instant; a file
    changed by hand (a checkpoint copied over another) changes it, and the
    stage runs again. ``output`` may be a file; a missing one digests as empty.
    The empty lock files lenspair's readers make (``DS/.lenspair-dataset.lock``,
    made by the train stage after the dataset stage) are no output.
    """
    digest = hashlib.sha256()
    if output.is_file():
        files = [(output.name, output)]
    else:
        files = sorted(
            (os.path.relpath(path, output), path)
            for path in output.rglob("*")
            if path.is_file() and not _lock_file(path)
        )
    for relative, path in files:
        status = path.stat()
        digest.update(f"{relative}\0{status.st_size}\0{status.st_mtime_ns}\n".encode())
    return digest.hexdigest()


def _lock_file(path: Path) -> bool:
    """Whether ``path`` is one of lenspair's lock files (``.lenspair-*.lock``)."""
    return path.name.startswith(".lenspair-") and path.name.endswith(".lock")


def run_stage(
    out: Path,
    stage: Stage,
    cli_main: Callable[[list[str]], int],
    reuse: bool = True,
    later: Sequence[Stage] = (),
) -> tuple[float, bool]:
    """Run one stage unless ``reuse`` and a finished marker with the same arguments and inputs.

    Inputs are the YAML files named in the arguments: editing a sample scene
    makes its stages run again. So does an output changed since the stage
    finished (its digest differs), and :func:`run_stages` runs every later
    stage again with it. Before a stage runs, its marker and those of
    the ``later`` stages (which read what it writes) are removed: a demo
    killed while it ran, or before they ran again, left an earlier run's
    markers beside a partial or stale output, and the rerun reused them.

    A stage with a ``resume_argv``, stopped while it ran with the same
    arguments and inputs (its ``.started.json`` record), continues with that
    command instead of starting over.

    Returns:
        (seconds spent, whether the stage was reused).
    """
    marker = _marker(out, stage)
    edited = False  # finished, then its output changed: nothing in it is to be resumed
    if reuse and marker.is_file() and stage.output.exists():
        recorded = _read_marker(marker)
        edited = recorded.get("output") != output_digest(stage.output)
        if (
            recorded.get("argv") == list(stage.argv)
            and not edited
            and recorded.get("inputs", {}) == _fingerprint(stage)
        ):
            return float(recorded.get("seconds", 0.0)), True
    started = {"argv": list(stage.argv), "inputs": _fingerprint(stage)}
    # stopped while it ran, with the same inputs since: continue it, not start over
    resuming = (
        reuse
        and not edited
        and bool(stage.resume_argv)
        and stage.resume_file is not None
        and stage.resume_file.is_file()
        and _read_marker(_started(out, stage)) == started
    )
    for stale in (stage, *later):
        _marker(out, stale).unlink(missing_ok=True)
    for stale in later:  # they will read what this stage writes now
        _started(out, stale).unlink(missing_ok=True)
    # the earlier report described outputs this stage now replaces: a stopped rerun
    # left it beside them, every stage still marked reused
    for name in REPORT_FILES:
        (out / name).unlink(missing_ok=True)
    # A resumable stage picks up where it stopped, unless what it read changed.
    keep = resuming or (stage.resumable and reuse and not edited)
    if stage.output.exists() and not keep:
        remove_path(stage.output)
    if not resuming:
        atomic_write_json(_started(out, stage), started)
    argv = stage.resume_argv if resuming else stage.argv
    print(f"\n[{stage.name}] lenspair {shlex.join(argv)}", file=sys.stderr, flush=True)
    start = time.perf_counter()
    code = cli_main(list(argv))
    seconds = time.perf_counter() - start
    if code == INTERRUPTED:  # Ctrl-C in the stage: the demo was stopped, nothing failed
        raise KeyboardInterrupt
    if code == TERMINATED:  # SIGTERM, likewise
        raise Terminated
    if code != 0:
        if resuming:  # it may fail again the same way: the rerun starts the stage over
            _started(out, stage).unlink(missing_ok=True)
        raise DemoError(f"stage {stage.name} failed (exit code {code}); rerun to resume")
    record = {
        "argv": list(stage.argv),
        "inputs": _fingerprint(stage),
        "output": output_digest(stage.output),
        "seconds": round(seconds, 2),
    }
    atomic_write_json(marker, record)
    _started(out, stage).unlink(missing_ok=True)
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

"""The files of a training run folder: paths, metrics CSV, log file, TensorBoard.

A run folder (written by :func:`lenspair.model.training.loop.fit`) holds::

    RUN/config.yaml              resolved configuration (+ runtime: what really ran)
    RUN/checkpoints/last.pt      after every epoch (and at a budget stop)
    RUN/checkpoints/best.pt      best validation PSNR so far
    RUN/metrics.csv              one row per epoch (columns: METRICS_COLUMNS)
    RUN/train.log                the log, warnings included
    RUN/samples.png              input | output | target of a few validation images
    RUN/tensorboard/             when TensorBoard is installed
    RUN/.lock                    held by the process writing the run (:class:`RunLock`)
"""

import contextlib
import csv
import io
import logging
import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lenspair.core.errors import first_line
from lenspair.core.folderlock import lock_file
from lenspair.core.fsutil import atomic_write_text
from lenspair.core.leftovers import remove_leftovers
from lenspair.model.errors import ModelError
from lenspair.model.training.run_state import RunState

log = logging.getLogger(__name__)

METRICS_COLUMNS = (
    "epoch",
    "step",
    "seconds",
    "loss_g",
    "loss_d",
    "adversarial",
    "feature_matching",
    "perceptual",
    "fidelity",
    "skipped_steps",
    "val_psnr",
    "val_ssim",
    "best_psnr",
)
"""Columns of ``RUN/metrics.csv`` (one row per epoch, or per budget stop).

``epoch`` counts completed epochs. A budget stop mid-epoch writes a row whose
``epoch`` is the count completed before it and whose ``step`` says where it
stopped; the log names that validation by the epoch under way, counting from
1 as the progress bar does (``epoch 1 step 3`` is the row ``0,3``). A resume
keeps the rows its ``last.pt`` vouches for by these two columns, so their
meaning stays as it is.
"""


@dataclass(frozen=True)
class RunPaths:
    """The files of a run folder."""

    root: Path

    @property
    def config(self) -> Path:
        """``RUN/config.yaml``: the resolved configuration."""
        return self.root / "config.yaml"

    @property
    def last(self) -> Path:
        """``RUN/checkpoints/last.pt``."""
        return self.root / "checkpoints" / "last.pt"

    @property
    def best(self) -> Path:
        """``RUN/checkpoints/best.pt``."""
        return self.root / "checkpoints" / "best.pt"

    @property
    def metrics(self) -> Path:
        """``RUN/metrics.csv``."""
        return self.root / "metrics.csv"

    @property
    def log(self) -> Path:
        """``RUN/train.log``."""
        return self.root / "train.log"

    @property
    def samples(self) -> Path:
        """``RUN/samples.png``: input | output | target of a few validation images."""
        return self.root / "samples.png"

    @property
    def tensorboard(self) -> Path:
        """``RUN/tensorboard/`` (only when TensorBoard is installed)."""
        return self.root / "tensorboard"


LOCK_FILE = ".lock"
"""``RUN/.lock``: ``flock``-ed by the process writing the run, for the run's life."""

_HELD: set[int] = set()
"""Descriptors of the run locks this process holds (closed in its forked children)."""


def _forget_held_locks() -> None:
    """In a forked child (a DataLoader worker), close the run locks' descriptors it inherited.

    The lock stays its parent's; a worker that outlives a killed run by the
    seconds it takes to notice would otherwise hold it and refuse the resume.
    """
    for descriptor in _HELD:
        with contextlib.suppress(OSError):
            os.close(descriptor)
    _HELD.clear()


os.register_at_fork(after_in_child=_forget_held_locks)


def busy_message(root: Path) -> str:
    """The refusal of a run folder another process is writing (one line naming it)."""
    return (
        f"{root}: another lenspair train is writing this run folder; run this one when that "
        "one has finished, or choose another --out"
    )


class RunLock:
    """The lock of a run folder: one process at a time writes a run (``train``, ``tradeoff``).

    Two processes writing one folder (a ``--resume`` started beside the run
    it resumes) both trained to the end, overwriting each other's
    ``last.pt``, ``best.pt`` and ``metrics.csv``. The lock is ``flock`` on
    :data:`LOCK_FILE` (:func:`~lenspair.core.folderlock.lock_file`), as
    ``capture-ingest`` locks its output. On a file system without locks the
    run goes on, with a warning.
    """

    def __init__(self, root: Path) -> None:
        """The lock of run folder ``root`` (not taken yet)."""
        self.root = Path(root)
        self.descriptor: int | None = None

    @property
    def held(self) -> bool:
        """Whether this process holds it (or the file system has no locks)."""
        return self.descriptor is not None

    def take(self) -> bool:
        """Take the lock of the existing run folder; False when another process holds it.

        Raises:
            OSError: the lock file cannot be created (a read-only folder: named).
        """
        if self.held:
            return True
        descriptor = lock_file(self.root / LOCK_FILE, "train")
        if descriptor is None:
            return False
        self.descriptor = descriptor
        _HELD.add(descriptor)
        return True

    def release(self) -> None:
        """Let the lock go (nothing when it is not held)."""
        if self.descriptor is not None:
            _HELD.discard(self.descriptor)
            os.close(self.descriptor)
            self.descriptor = None


def remove_run_leftovers(paths: RunPaths) -> None:
    """Delete temporaries (half-written checkpoints, logs) of killed sessions of this run."""
    for folder in (paths.root, paths.last.parent):
        remove_leftovers(folder)


def metrics_row(
    state: RunState, means: dict[str, float], skipped: int, val_psnr: float, val_ssim: float
) -> dict[str, str]:
    """One row of ``RUN/metrics.csv``, keyed by :data:`METRICS_COLUMNS`.

    Args:
        state: the run's progress after the validation.
        means: mean training losses of the epoch (missing ones are left empty).
        skipped: steps the NaN/Inf guard skipped so far.
        val_psnr: validation PSNR, dB.
        val_ssim: validation SSIM.

    """
    values: dict[str, object] = {
        "epoch": state.epoch,
        "step": state.step,
        "seconds": f"{state.seconds:.1f}",
        "skipped_steps": skipped,
        "val_psnr": f"{val_psnr:.4f}",
        "val_ssim": f"{val_ssim:.6f}",
        "best_psnr": f"{state.best_psnr:.4f}",
    }
    for name in ("loss_g", "loss_d", "adversarial", "feature_matching", "perceptual", "fidelity"):
        values[name] = f"{means[name]:.6g}" if name in means else ""
    return {column: str(values[column]) for column in METRICS_COLUMNS}


def read_metrics_rows(path: Path) -> list[dict[str, str]]:
    """The rows of a metrics CSV (``[]`` if there is no such file).

    Raises:
        ModelError: the file is not text or not CSV (one line naming it).
    """
    if not path.is_file():
        return []
    try:
        with path.open(newline="", encoding="utf-8") as handle:
            return list(csv.DictReader(handle))
    except (UnicodeDecodeError, csv.Error) as exc:
        raise ModelError(
            f"{path}: not a metrics table ({first_line(exc)}); move it aside to resume without "
            "the run's earlier rows"
        ) from None


def write_metrics_rows(path: Path, rows: list[dict[str, str]]) -> None:
    """Write ``rows`` as a metrics CSV with :data:`METRICS_COLUMNS` (atomically)."""
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=METRICS_COLUMNS, lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({column: row.get(column, "") for column in METRICS_COLUMNS})
    atomic_write_text(path, buffer.getvalue())


@contextlib.contextmanager
def run_logging(path: Path, enabled: bool) -> Iterator[None]:
    """Copy log records to ``RUN/train.log`` (INFO and up) while training.

    Processes other than rank 0 (``enabled=False``) log warnings and errors only.
    """
    package = logging.getLogger("lenspair.model")
    old_level = package.level
    if not enabled:
        package.setLevel(logging.WARNING)
        try:
            yield
        finally:
            package.setLevel(old_level)
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    handler = logging.FileHandler(path, encoding="utf-8")
    handler.setLevel(logging.INFO)
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    root = logging.getLogger()
    if package.getEffectiveLevel() > logging.INFO:
        package.setLevel(logging.INFO)
    root.addHandler(handler)
    try:
        yield
    finally:
        root.removeHandler(handler)
        handler.close()
        package.setLevel(old_level)


@contextlib.contextmanager
def tensorboard_writer(folder: Path, enabled: bool) -> Iterator[Any]:
    """A TensorBoard ``SummaryWriter`` when enabled and installed, else ``None``."""
    if not enabled:
        yield None
        return
    try:  # here, not at the top: tensorboard is optional, its absence is logged
        from torch.utils.tensorboard import SummaryWriter
    except ImportError:
        log.info("TensorBoard is not installed; metrics go to metrics.csv only")
        yield None
        return
    writer = SummaryWriter(log_dir=str(folder))
    try:
        yield writer
    finally:
        writer.close()

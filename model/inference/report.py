"""What a restore run did: :class:`RestoreReport`, written to ``OUT/restore_report.json``.

The report is also how ``--resume`` finds the settings and, for a bag, the
files of an earlier run (:mod:`lenspair.model.inference.resume`); its
:meth:`~RestoreReport.summary` is the line the CLI prints last.
"""

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from lenspair.core.wording import counted

REPORT_NAME = "restore_report.json"
"""Under OUT: the report of the run (see :class:`RestoreReport`)."""

RESTORE_LOCK = ".lenspair-restore.lock"
"""The file in OUT whose ``flock`` a restore holds while it writes OUT (hidden: no frame,
no output: the checks of OUT pass over it)."""


def is_restore_output(folder: Path) -> bool:
    """Whether ``folder`` is an earlier restore's OUT: it holds a restore's report.

    Its report and lock are then that run's, not the user's files.
    """
    try:
        report = json.loads((Path(folder) / REPORT_NAME).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(report, dict) and {"kind", "restored", "output"} <= report.keys()


SAID_PROBLEMS = 20
"""Problems the CLI says, one line each, before it points to the report for the rest."""


@dataclass
class RestoreReport:
    """What a run did; written to ``OUT/restore_report.json``.

    Attributes:
        input: the input path.
        kind: ``image``, ``folder``, ``euroc``, ``folders``, ``rosbag1`` or ``rosbag2``.
        output: the folder, or the bag written.
        model: the backend's description.
        cameras: cameras restored (recordings and bags).
        frames_read: frames met (decoded or not).
        restored: frames the network restored and wrote in this run.
        resumed: frames already written by an earlier run (``--resume``).
        skipped: frames judged clean and copied unchanged.
        skipped_frames: their names, in input order.
        failed: frames that could not be restored (copied unchanged).
        problems: ``{"frame", "reason"}`` per failed frame, plus input-level ones.
        seconds: wall time of the run.
        settings: what decides the output bytes
            (:func:`~lenspair.model.inference.resume.run_settings`);
            ``--resume`` refuses an OUT written with other ones.
        source_files: bags: ``[name, size, mtime_ns]`` of the files the bag
            was read from; ``--resume`` of a complete run keeps its bag while
            they are unchanged (:meth:`~lenspair.model.inference.bag_sink.BagSink.finished`).
        output_files: bags: the same of the bag written, which must be unchanged too.
        forced_tile: ``WxH`` of a model of that fixed size, when this run ran
            frames of another size in tiles of it (they differ from the
            checkpoint's output at the tile seams:
            :class:`~lenspair.model.inference.backends.ForcedTiles`); None when
            every frame ran whole or in ``--tile`` tiles.
    """

    input: str
    kind: str
    output: str
    model: str
    cameras: list[str]
    frames_read: int = 0
    restored: int = 0
    resumed: int = 0
    skipped: int = 0
    skipped_frames: list[str] = field(default_factory=list)
    failed: int = 0
    problems: list[dict[str, str]] = field(default_factory=list)
    seconds: float = 0.0
    settings: dict[str, Any] = field(default_factory=dict)
    source_files: list[list[Any]] = field(default_factory=list)
    output_files: list[list[Any]] = field(default_factory=list)
    forced_tile: str | None = None

    @property
    def frames_per_second(self) -> float:
        """Frames read per second of wall time."""
        return self.frames_read / self.seconds if self.seconds > 0 else 0.0

    def summary(self) -> str:
        """The final line: frames, time, frames/s, where the output is, problems if any."""
        return (
            f"restore: {counted(self.frames_read, 'frame')} ({self.restored} restored, "
            f"{self.resumed} resumed, {self.skipped} skipped, {self.failed} failed) "
            f"in {self.seconds:.1f} s, "
            f"{self.frames_per_second:.1f} frames/s -> {self.output}"
            + (f"; {len(self.problems)} problem(s) in {REPORT_NAME}" if self.problems else "")
        )

    def problem_lines(self, limit: int = SAID_PROBLEMS) -> list[str]:
        """The problems as the CLI says them, at most ``limit`` and how many more.

        Every one is in the report; the first ``limit`` are said, one line
        each (``frame: reason``, or the reason alone where it names the file
        or the problem is the input's), so that a bad frame is named where
        the run is watched.
        """
        lines = [  # a reason that names its file already is not prefixed with it
            p["reason"] if p["frame"] in p["reason"] else f"{p['frame']}: {p['reason']}"
            for p in self.problems[:limit]
        ]
        if len(self.problems) > limit:
            lines.append(f"... and {len(self.problems) - limit} more in {REPORT_NAME}")
        return lines

    def as_dict(self) -> dict[str, Any]:
        """Plain data for JSON (``complete``: the run finished)."""
        return {
            **asdict(self),
            "frames_per_second": round(self.frames_per_second, 3),
            "complete": True,
        }

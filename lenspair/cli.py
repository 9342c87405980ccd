"""The ``lenspair`` command line: one thin dispatcher over the stage packages.

Each subcommand lives in ``lenspair/commands/<name>.py`` and provides
``add_arguments(parser)`` and ``run(args) -> int``; its module docstring is
its ``--help`` description. Only the chosen subcommand's module is imported,
so ``lenspair simulate`` does not pay for importing torch.
"""

import argparse
import contextlib
import errno
import importlib
import logging
import os
import signal
import sys
import threading
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType
from typing import Any, NoReturn

from lenspair import __version__
from lenspair.commands.argtypes import expand_topics
from lenspair.core.errors import LenspairError

# name -> (module, one-line summary). A plain table: no registry magic.
COMMANDS: dict[str, tuple[str, str]] = {
    "simulate": ("lenspair.commands.simulate", "render a scene spec into a stereo recording"),
    "realism": (
        "lenspair.commands.realism",
        "do synthetic drops look real: statistics beside real ones",
    ),
    "calibrate": ("lenspair.commands.calibrate", "calibrate a stereo rig from board views"),
    "capture-ingest": (
        "lenspair.commands.capture_ingest",
        "turn a recording into registered 540x360 (obstructed, clean) pairs",
    ),
    "dataset-build": (
        "lenspair.commands.dataset_build",
        "curate ingested recordings into train/val/test splits",
    ),
    "train": ("lenspair.commands.train", "train the shallow GAN (synthetic or real pairs)"),
    "eval": ("lenspair.commands.eval", "measure PSNR/SSIM and latency of a checkpoint"),
    "tradeoff": ("lenspair.commands.tradeoff", "accuracy-versus-time table and plot of variants"),
    "export": ("lenspair.commands.export", "export a checkpoint to ONNX and TorchScript"),
    "restore": ("lenspair.commands.restore", "restore images, folders, recordings and bags"),
    "train-detector": (
        "lenspair.commands.train_detector",
        "train the small anomaly detector (obstructed?, kind, where)",
    ),
    "detect": ("lenspair.commands.detect", "judge frames: obstructed?, by what, where"),
    "demo": ("lenspair.commands.demo", "run the whole pipeline on the bundled sample scenes"),
}


INTERRUPTED = 130
"""The exit code after Ctrl-C (128 + SIGINT, as shells report a process it stopped)."""

TERMINATED = 143
"""The exit code after SIGTERM (128 + SIGTERM)."""


class Terminated(KeyboardInterrupt):
    """SIGTERM (``docker stop``, systemd, a ROS launch shutting down), raised as Ctrl-C is.

    So a command stopped that way ends as after Ctrl-C: its ``finally`` blocks
    run (worker pools stopped, temporaries removed) and it says how to resume;
    without it Python died on the spot, leaving that to the next run.
    """


@contextlib.contextmanager
def _sigterm_as_interrupt() -> Iterator[None]:
    """Raise :class:`Terminated` on SIGTERM meanwhile, in this process only.

    Left alone when SIGTERM already has a handler (an embedding program's,
    or this one's in a nested call such as the demo's stages), off the main
    thread, and under ``torchrun`` with several processes (it stops every
    rank with SIGTERM, and a rank waiting in a collective could not run the
    handler: the default ending is the clean one there). A forked worker
    that inherits the handler ends as by default.
    """
    if (
        threading.current_thread() is not threading.main_thread()
        or signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL
        or int(os.environ.get("WORLD_SIZE", "1") or 1) > 1
    ):
        yield
        return
    owner = os.getpid()

    def stop(signum: int, frame: object) -> None:
        if os.getpid() != owner:  # a forked worker: die of it, as before
            signal.signal(signal.SIGTERM, signal.SIG_DFL)
            os.kill(os.getpid(), signal.SIGTERM)
            return
        raise Terminated

    signal.signal(signal.SIGTERM, stop)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)


def _load(name: str) -> ModuleType:
    return importlib.import_module(COMMANDS[name][0])


class _OneLineParser(argparse.ArgumentParser):
    """An argument parser whose errors are one line naming the option (exit code 2).

    A command's parser (``strict``) refuses the arguments it does not know
    itself, so that its message names the command (``lenspair capture-ingest:
    error: unrecognized arguments: --threads 2``): argparse hands a
    subcommand's leftovers up to the top-level parser, which blamed
    ``lenspair`` and pointed at ``lenspair --help``.
    """

    strict = False

    def parse_known_args(self, *args: Any, **kwargs: Any) -> Any:
        """As argparse's; a ``strict`` parser refuses leftovers with its own error."""
        namespace, extras = super().parse_known_args(*args, **kwargs)
        if self.strict and extras:
            self.error(f"unrecognized arguments: {' '.join(extras)}")
        return namespace, extras

    def error(self, message: str) -> NoReturn:
        """Print ``PROG: error: MESSAGE`` (no usage block) and exit with code 2."""
        self.exit(2, f"{self.prog}: error: {message}; see '{self.prog} --help'\n")


EXIT_CODES = (
    "exit codes: 0 done; 2 a user error (one line naming the file or option); 1 the file "
    "system refused a write (read-only, full disk, permissions: one line naming the path), "
    f"or dataset-build --verify found problems; {INTERRUPTED} after Ctrl-C and {TERMINATED} "
    "after SIGTERM (rerun the command to resume where it can)"
)
"""What every command's exit status means (``lenspair --help``)."""


def build_parser(selected: str | None) -> argparse.ArgumentParser:
    """Build the parser; only ``selected``'s module is imported for its arguments."""
    parser = _OneLineParser(
        prog="lenspair",
        description="Paired camera-anomaly datasets from stereo rigs, and a fast shallow GAN "
        "that removes raindrops, dust and dirt. Run 'lenspair COMMAND --help' for details.",
        epilog=EXIT_CODES,
    )
    parser.add_argument("--version", action="version", version=f"lenspair {__version__}")
    parser.add_argument(
        "-v",
        "--verbose",
        action="store_true",
        help="log debug messages, and a file-system refusal's traceback",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, (_, summary) in COMMANDS.items():
        if name == selected:
            module = _load(name)
            command = sub.add_parser(
                name,
                help=summary,
                description=module.__doc__,
                formatter_class=argparse.RawDescriptionHelpFormatter,
            )
            assert isinstance(command, _OneLineParser)  # add_parser makes the parent's class
            command.strict = True
            module.add_arguments(command)
            # also after the command (`lenspair restore -v ...`), where users type it; SUPPRESS
            # keeps an absent one from resetting a -v given before the command
            command.add_argument(
                "-v",
                "--verbose",
                action="store_true",
                default=argparse.SUPPRESS,
                help="log debug messages, and a file-system refusal's traceback (also "
                "before COMMAND)",
            )
        else:
            sub.add_parser(name, help=summary, add_help=False)
    return parser


REFUSALS = frozenset(
    {errno.EACCES, errno.EPERM, errno.EROFS, errno.ENOSPC, errno.EDQUOT, errno.EEXIST,
     errno.ENOTDIR, errno.EISDIR, errno.ENAMETOOLONG, errno.EIO, errno.EFBIG, errno.EBUSY,
     errno.EXDEV, errno.ENOENT}
)  # fmt: skip
"""``errno`` values of a file system refusing a write: one line, exit 1 (``-v``: traceback).

``EBUSY`` and ``EXDEV`` are a rename refused: a mount point (a Docker volume given
as an output folder) cannot be renamed away, nor a folder renamed across file systems.
``ENOENT`` is a path that does not exist and cannot be made there (``--out
/proc/x``: such a file system refuses new folders with it); the inputs' own
absence is checked, and named, before any work.
"""


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; returns the process exit code."""
    argv = expand_topics(list(sys.argv[1:] if argv is None else argv))
    selected = next((a for a in argv if a in COMMANDS), None)
    try:
        parser = build_parser(selected)  # imports the command's module: numpy, OpenCV, torch
    except KeyboardInterrupt:  # Ctrl-C this early has nothing to resume
        print(f"lenspair {selected or ''}: interrupted".replace(" :", ":"), file=sys.stderr)
        return INTERRUPTED
    if not argv:
        parser.print_help(sys.stderr)
        return 2
    first = next((a for a in argv if not a.startswith("-")), None)
    if selected is None and first is not None:
        print(
            f"lenspair: unknown command {first!r}; valid commands: {', '.join(COMMANDS)}",
            file=sys.stderr,
        )
        return 2
    args = parser.parse_args(argv)
    logging.basicConfig(format="%(levelname)s %(name)s: %(message)s")
    # lenspair's own INFO lines; other libraries' only from WARNING up, unless -v: torch
    # logged "FakeTensor cache stats" after an interrupted run's last line
    logging.getLogger().setLevel(logging.DEBUG if args.verbose else logging.WARNING)
    logging.getLogger("lenspair").setLevel(logging.DEBUG if args.verbose else logging.INFO)
    try:
        module = _load(args.command)
        with _sigterm_as_interrupt(), reading_inputs(module, args):
            return int(module.run(args))
    except LenspairError as exc:
        _end_bar_line(interrupted=False)
        print(f"lenspair {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # the file system refused: read-only, full, a file where a folder goes
        if args.verbose or exc.errno not in REFUSALS:
            raise  # anything else may be a bug: its traceback is wanted
        where = " -> ".join(str(f) for f in (exc.filename, exc.filename2) if f is not None)
        reason = exc.strerror or str(exc)
        _end_bar_line(interrupted=False)
        print(
            f"lenspair {args.command}: error: {where + ': ' if where else ''}{reason}",
            file=sys.stderr,
        )
        # a name too long, or a folder that cannot be made where asked, is the user's to
        # change, as any mistyped path: a user error
        return 2 if exc.errno in (errno.ENAMETOOLONG, errno.ENOENT) else 1
    except KeyboardInterrupt as exc:
        # restore and train continue only when asked; the other commands resume by themselves
        hint = "rerun with --resume to continue" if hasattr(args, "resume") else "rerun to resume"
        own_hint = getattr(_load(args.command), "interrupt_hint", None)  # a command may know better
        if own_hint is not None:
            hint = own_hint(args) or hint
        stopped = "terminated" if isinstance(exc, Terminated) else "interrupted"
        _end_bar_line(interrupted=True)
        print(f"lenspair {args.command}: {stopped}; {hint}", file=sys.stderr)
        return TERMINATED if isinstance(exc, Terminated) else INTERRUPTED


def reading_inputs(
    module: ModuleType, args: argparse.Namespace
) -> contextlib.AbstractContextManager[None]:
    """Hold the lock of each lenspair dataset the command reads, while it runs.

    A command lists the arguments that name datasets it reads in
    ``DATASET_ARGUMENTS`` (a path, or a list of paths, each); no
    ``dataset-build --overwrite`` replaces those meanwhile
    (:func:`lenspair.dataset.output.reading_datasets`).
    """
    names: tuple[str, ...] = getattr(module, "DATASET_ARGUMENTS", ())
    paths: list[Path | None] = []
    for name in names:
        value = getattr(args, name, None)
        paths.extend(value if isinstance(value, list) else [value])
    if not any(path is not None for path in paths):
        return contextlib.nullcontext()
    # Imported here, not at the top: only commands reading a dataset load the package.
    from lenspair.dataset.output import reading_datasets

    return reading_datasets(path for path in paths if path is not None)


def _end_bar_line(interrupted: bool) -> None:
    """Start the command's last line on a line of its own.

    In a log file a progress bar's last state stays on its line, unterminated
    (:func:`lenspair.core.progress.bar_shown`), and an error read on after it:
    "...2/12 [00:02<00:12, 1.25s/frame]lenspair restore: error: ...". In a
    terminal a closed bar clears its line; only Ctrl-C's echoed ``^C`` is left.
    """
    if sys.stderr.isatty():
        if interrupted:
            print(file=sys.stderr)
        return
    bars = sys.modules.get("lenspair.core.progress")  # none shown: its module is not loaded
    if bars is not None and bars.bar_shown():
        print(file=sys.stderr)


if __name__ == "__main__":  # python -m lenspair.cli, as torchrun -m runs it
    sys.exit(main())

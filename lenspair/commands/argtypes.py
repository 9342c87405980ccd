"""Argparse value types shared by the subcommands (one-line errors naming the option)."""

import argparse
import math
import os
from collections.abc import Callable
from pathlib import Path

from lenspair.core.config import MAX_SEED
from lenspair.core.samples import file_or_sample
from lenspair.core.sizes import parse_size

MAX_COUNT = 2**31 - 1
"""The largest count an option takes: C's int, which torch, OpenCV and multiprocessing
take their counts as (a larger one ended in an OverflowError traceback)."""

MAX_WORKERS = 256
"""The most worker processes or threads an option starts (2 per core on a large machine)."""


def positive_int(text: str, most: int = MAX_COUNT) -> int:
    """Argparse type: an integer from 1 to ``most``."""
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}")
    if value > most:
        raise argparse.ArgumentTypeError(f"expected at most {most}, got {text!r}")
    return value


def non_negative_int(text: str, most: int = MAX_COUNT) -> int:
    """Argparse type: an integer from 0 to ``most`` (:func:`positive_int`'s, with 0)."""
    try:
        zero = int(text) == 0
    except ValueError:
        zero = False
    return 0 if zero else positive_int(text, most)


MAX_TIMED_RUNS = 10_000
"""The most timed runs a latency figure takes (a median of 10000 is as sure as it gets)."""


def timed_runs(text: str) -> int:
    """Argparse type: ``--latency-runs``, 0 (no timing) to :data:`MAX_TIMED_RUNS`."""
    return non_negative_int(text, MAX_TIMED_RUNS)


def worker_count(text: str) -> int:
    """Argparse type: a number of worker processes or threads, 1 to :data:`MAX_WORKERS`."""
    return positive_int(text, MAX_WORKERS)


def finite_float(text: str) -> float:
    """Argparse type: a finite number of any sign (NaN and inf refused)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


MAX_TIME_OFFSET_MS = 9.2e12
"""The most ``--time-offset`` takes either way: stamps are 64-bit ns (2**63 ns ~ 9.22e12 ms)."""


def time_offset_ms(text: str) -> float:
    """Argparse type of ``--time-offset``: milliseconds, finite, within the 64-bit ns range."""
    value = finite_float(text)
    if abs(value) > MAX_TIME_OFFSET_MS:
        raise argparse.ArgumentTypeError(
            f"expected at most {MAX_TIME_OFFSET_MS:g} ms either way (the range of ns stamps), "
            f"got {text!r}"
        )
    return value


def float_at_least(low: float, *, above: bool = False) -> Callable[[str], float]:
    """Argparse type: a finite number >= ``low`` (> ``low`` with ``above``); NaN/inf refused."""

    def parse(text: str) -> float:
        value = finite_float(text)
        if value < low or (above and value == low):
            raise argparse.ArgumentTypeError(
                f"expected a number {'>' if above else '>='} {low:g}, got {text!r}"
            )
        return value

    parse.__name__ = "number"  # argparse names the type in its messages
    return parse


def size(minimum: int = 1, maximum: int | None = None) -> Callable[[str], tuple[int, int]]:
    """Argparse type: ``WIDTHxHEIGHT`` -> ``(width, height)``, sides in ``minimum .. maximum``."""

    def parse(text: str) -> tuple[int, int]:
        try:
            return parse_size(text, minimum, maximum)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    parse.__name__ = "size"
    return parse


DEFAULT_SPLIT = "test"
"""The split of a dataset root that ``eval`` and ``realism`` read without ``--split``."""


def split_name(text: str) -> str:
    """Argparse type: the name of a dataset's split folder (``train``, ``val``, ``test``).

    A path (``test/input``, ``../other``) would read pairs outside the
    dataset's splits and, in ``eval``, nest the default report folder.
    """
    if text in ("", ".", "..") or "/" in text or "\\" in text:
        raise argparse.ArgumentTypeError(
            f"expected the name of a split folder (train, val, test), not a path: {text!r}"
        )
    return text


def fraction(text: str) -> float:
    """Argparse type: a finite number in [0, 1]."""
    value = finite_float(text)
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"expected a number in [0, 1], got {text!r}")
    return value


def open_fraction(text: str) -> float:
    """Argparse type: a finite number strictly between 0 and 1 (a probability threshold)."""
    value = finite_float(text)
    if not 0.0 < value < 1.0:
        raise argparse.ArgumentTypeError(f"expected a number in (0, 1), got {text!r}")
    return value


def _exists(path: Path, text: str) -> bool:
    """Whether ``path`` exists; a path the system cannot even look up is an argument error.

    ``Path.exists`` raises on a name over the file system's limit (a traceback).
    """
    try:
        path.stat()
    except FileNotFoundError:
        return False
    except NotADirectoryError:
        return False
    except OSError as exc:
        raise argparse.ArgumentTypeError(f"{text!r}: {exc.strerror}") from None
    return True


def _refuse_dangling(part: Path, path: Path, text: str) -> None:
    """Refuse ``part`` (``path`` or a folder above it) when it is a symbolic link to nothing.

    A link whose target is missing (``out -> /media/ssd/run``, the disk not
    mounted) looks absent, and creating the folder then failed with "File
    exists", after the work (``eval`` scored every pair first).
    """
    if not part.is_symlink():
        return
    target = os.readlink(part)
    where = f"{text!r} is" if part == path else f"{text!r} lies inside {str(part)!r},"
    raise argparse.ArgumentTypeError(
        f"{where} a symbolic link to {target}, which does not exist (a disk not mounted?)"
    )


def out_folder(text: str) -> Path:
    """Argparse type: an output folder: new, or an existing folder (not a file, nor inside one).

    An empty name is refused: ``Path("")`` is the current folder, and ``--out ""``
    (an unset shell variable) wrote a run's files among the user's own. So is
    a symbolic link to nothing, on the way or at the end (:func:`_refuse_dangling`).
    """
    if not text.strip():
        raise argparse.ArgumentTypeError("an empty name; give a folder (. for this one)")
    path = Path(text)
    for part in (path, *path.parents):
        if _exists(part, text):
            if not part.is_dir():
                where = "is a file" if part == path else f"lies inside the file {part}"
                raise argparse.ArgumentTypeError(f"{text!r} {where}; give a folder")
            break
        _refuse_dangling(part, path, text)
    return path


def out_file(text: str) -> Path:
    """Argparse type: a file to write: not an existing folder, nor inside a file."""
    if text.endswith(("/", os.sep)):  # Path drops the slash: a file named as the folder
        raise argparse.ArgumentTypeError(f"{text!r} names a folder; give a file name")
    path = Path(text)
    if _exists(path, text):
        if path.is_dir():
            raise argparse.ArgumentTypeError(f"{text!r} is a folder; give a file name")
    else:  # a file written in place of a link to nothing would replace the user's link
        _refuse_dangling(path, path, text)
    out_folder(str(path.parent))
    return path


def random_seed(text: str) -> int:
    """Argparse type: a random seed, an integer in ``0 .. MAX_SEED``."""
    try:
        value = int(text)
    except ValueError:
        value = -1
    if not 0 <= value <= MAX_SEED:
        raise argparse.ArgumentTypeError(f"expected an integer 0 .. {MAX_SEED}, got {text!r}")
    return value


def input_path(text: str) -> Path:
    """Argparse type: a file or folder to read; one this user may not read is refused here.

    Found later, a refused read was the file system's exit 1 ("the file system
    refused a write"), named a file the recording never had (a layout probe's
    ``metadata.yaml``), or called a checkpoint "not a readable torch file", as
    if damaged. A path that does not exist passes: each command says what it
    expected there (and resolves the bundled names).
    """
    path = Path(text)
    if path.exists():
        folder = path.is_dir()
        if not os.access(path, os.R_OK | (os.X_OK if folder else 0)):
            kind = "folder" if folder else "file"
            raise argparse.ArgumentTypeError(
                f"{text!r}: permission denied (this user may not read the {kind})"
            )
    return path


def detector_file(text: str) -> Path:
    """Argparse type: a detector checkpoint; ``detector.pt`` alone is the bundled one."""
    return file_or_sample(str(input_path(text)), ".pt")


class _Topics(argparse.Action):
    """Stores ``--topics CAM0 CAM1`` as a ``(cam0, cam1)`` tuple of two different topics."""

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: object,
        option_string: str | None = None,
    ) -> None:
        words = [str(v).strip() for v in values] if isinstance(values, list) else []
        if len(words) != 2 or not all(words) or words[0] == words[1]:
            parser.error(f"--topics: expected two different topics, got {' '.join(words)!r}")
        setattr(namespace, self.dest, (words[0], words[1]))


def expand_topics(argv: list[str]) -> list[str]:
    """``--topics A,B`` (the form capture-ingest always took) as ``--topics A B``.

    The option takes exactly two words (``nargs=2``): one that took "one or
    more" swallowed the positional arguments written after it.
    """
    expanded: list[str] = []
    after_option = False
    for token in argv:
        if token.startswith("--topics="):
            expanded.append("--topics")
            token = token.split("=", 1)[1]
            after_option = True
        if after_option and "," in token:
            expanded.extend(part.strip() for part in token.split(","))
        else:
            expanded.append(token)
        after_option = token == "--topics"
    return expanded


def add_topics_option(parser: argparse.ArgumentParser) -> None:
    """``--topics CAM0 CAM1``, the same in every command that reads bags."""
    parser.add_argument(
        "--topics",
        nargs=2,
        action=_Topics,
        default=None,
        metavar=("CAM0", "CAM1"),
        help="bags: the image topics of cam0 and cam1 (also CAM0,CAM1; default: chosen from "
        "the topic names: cam0/cam1 or left/right, or the only two)",
    )


def add_time_offset_option(parser: argparse.ArgumentParser, command: str, kept: str) -> None:
    """``--time-offset MS``, how far cam1's clock runs ahead, in every command that pairs frames.

    ``command`` names who warns of differing clocks, ``kept`` what records the pairs' stamps.
    """
    parser.add_argument(
        "--time-offset",
        type=time_offset_ms,
        default=0.0,
        metavar="MS",
        help="how far cam1's clock runs ahead of cam0's, in ms: cam1's stamps less MS are "
        f"paired with cam0's ({kept} keep the recorded stamps; the report keeps MS). For "
        f"cameras without a common clock, when {command} says the clocks seem to differ (0)",
    )


def add_convention_option(parser: argparse.ArgumentParser) -> None:
    """``--convention``, the metric convention, with the same help in eval and tradeoff."""
    parser.add_argument(
        "--convention",
        choices=("skimage-gaussian", "deraindrop-y"),
        default="skimage-gaussian",
        help="how PSNR/SSIM are computed: skimage-gaussian (scikit-image, Gaussian SSIM "
        "window; default), or deraindrop-y (on the luma Y, as DeRaindrop's published numbers)",
    )


def add_device_option(parser: argparse.ArgumentParser, purpose: str = "") -> None:
    """``--device auto|cpu|cuda``, with the same help in every command."""
    parser.add_argument(
        "--device",
        choices=("auto", "cpu", "cuda"),
        default="auto",
        help=(f"{purpose}: " if purpose else "")
        + "where the networks run: auto (a GPU when one is available, else the CPU), cpu "
        "or cuda (default auto). Pick the GPU with CUDA_VISIBLE_DEVICES.",
    )

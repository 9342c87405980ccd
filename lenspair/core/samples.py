"""The bundled sample files (scene specs, a Kalibr camchain), found as package data.

They ship inside the installed package as ``lenspair.calib_samples`` (the
repository's ``calib_samples/`` folder), so they are found the same way in an
editable install, a wheel and an sdist, whatever the working directory.
"""

import logging
from importlib import resources
from pathlib import Path

from lenspair.core.errors import LenspairError

log = logging.getLogger(__name__)

SAMPLES_PACKAGE = "lenspair.calib_samples"


def sample_names(suffix: str = ".yaml") -> list[str]:
    """File names of the bundled samples ending in ``suffix``, sorted."""
    root = resources.files(SAMPLES_PACKAGE)
    return sorted(p.name for p in root.iterdir() if p.name.endswith(suffix))


def sample_path(name: str) -> Path:
    """The file system path of one bundled sample, e.g. ``sample_path("rain.yaml")``.

    Raises:
        LenspairError: no bundled sample has that name (the message lists them).
    """
    resource = resources.files(SAMPLES_PACKAGE) / name
    if not resource.is_file():
        raise LenspairError(
            f"no bundled sample named {name!r}; available: {', '.join(sample_names())}"
        )
    return Path(str(resource))


def file_or_sample(text: str, suffix: str) -> Path:
    """A command-line file argument: the file when it exists, else a bundled sample.

    ``lenspair simulate rain --out rec`` and ``--detector detector.pt`` work
    from any folder: a name (with or without ``suffix``) that is not an
    existing file but names a bundled sample is that sample (a folder of
    that name, such as the output of an earlier run, does not hide it); anything else
    stays the path it was (and fails later as a missing file would).
    """
    path = Path(text)
    try:
        is_file = path.is_file()
    except OSError:  # a name too long for the file system: no such file, said where it is read
        return path
    if is_file or path.parent != Path("."):  # a folder named "rain" is not the scene
        return path
    names = sample_names(suffix)
    for candidate in (path.name, path.name + suffix):
        if candidate in names:
            local = Path(path.name + suffix)
            if local.is_file():  # the user's own file of that name, silently passed over
                log.warning(
                    "%s: the bundled sample %s; %s in this folder is not read (give %s for it)",
                    text,
                    candidate,
                    local,
                    local,
                )
            return sample_path(candidate)
    return path

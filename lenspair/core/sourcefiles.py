"""Name, size and modification time of the files a recording is read from.

A rerun of ``capture-ingest`` and a ``restore --resume`` keep the work of an
earlier run only while its input is unchanged, and must tell without
reading the input again (a bag can be tens of GB). A ROS 2 bag folder's own
size and time do not change when a storage file inside it is rewritten in
place (``cp`` onto the same name), so the files are stated one by one:
``metadata.yaml`` and the storage files it lists (``.db3``/``.mcap``, split
or compressed: the files ``rosbags`` opens). A folder whose ``metadata.yaml``
cannot be read, or lists no file, is stated file by file, all of them: what
it is read from cannot be told, so anything may matter.
"""

import functools
from pathlib import Path, PurePath
from typing import Any

import yaml

METADATA_FILE = "metadata.yaml"
"""A ROS 2 bag folder's index of its storage files."""


def source_fingerprint(source: Path) -> list[list[Any]]:
    """``[name, size, mtime_ns]`` of each file ``source`` is read from, sorted by name.

    Args:
        source: a file (a ROS 1 ``.bag``, a bare ``.db3``/``.mcap``): itself;
            a ROS 2 bag folder: ``metadata.yaml`` and the storage files it
            lists; another folder, or one whose ``metadata.yaml`` lists
            nothing readable: every file under it.

    Returns:
        One ``[name, size in bytes, modification time in ns]`` per file; a
        file listed but missing (or unreadable) has ``None`` for both, so
        that its return is noticed too.
    """
    source = Path(source)
    if not source.is_dir():
        return [_stated(source, source.name)]
    listed = _storage_names(source / METADATA_FILE)
    if listed is None:
        files = sorted(p for p in source.rglob("*") if p.is_file())
        return [_stated(p, p.name) for p in files]
    names = sorted({METADATA_FILE, *listed})
    return [_stated(source / name, name) for name in names]


def _stated(path: Path, name: str) -> list[Any]:
    try:
        info = path.stat()
    except OSError:
        return [name, None, None]
    return [name, info.st_size, info.st_mtime_ns]


def _storage_names(metadata: Path) -> tuple[str, ...] | None:
    """The storage file names ``metadata`` lists, or None when it lists none or cannot be read."""
    try:
        info = metadata.stat()
    except OSError:
        return None
    # stated for every frame of a recording: the YAML is parsed once per version of it
    return _parsed_names(metadata, info.st_size, info.st_mtime_ns)


@functools.lru_cache(maxsize=16)
def _parsed_names(metadata: Path, size: int, mtime_ns: int) -> tuple[str, ...] | None:
    """:func:`_storage_names` of one version (``size``, ``mtime_ns``) of ``metadata``."""
    del size, mtime_ns  # the cache key only: a rewritten file is parsed again
    try:
        document = yaml.safe_load(metadata.read_text(encoding="utf-8"))
        paths = document["rosbag2_bagfile_information"]["relative_file_paths"]
        # rosbags opens each by its name inside the folder, whatever folder it names
        names = tuple(PurePath(str(p)).name for p in paths)
    except (OSError, UnicodeDecodeError, yaml.YAMLError, KeyError, TypeError):
        return None
    return names or None

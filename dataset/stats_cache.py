"""Measured pair figures kept between builds, so a rerun decodes no image it has measured.

Decoding a pair's two images and measuring them
(:func:`~lenspair.dataset.curation.measure_pair`) is about 95 % of what
``dataset-build`` spends on a pair before writing; hashing its files, which the
build does anyway, is the rest. So each pair's figures are kept under a key
made of its files' SHA-256s, the anomaly delta, and a fingerprint of the code
and libraries that measure (:func:`code_fingerprint`): a build killed before it
finished, or a rebuild with other thresholds, reads them back. The key holds
everything the figures depend on, so a cached figure is the one measuring would
give, bit for bit, and the dataset is byte-identical with or without the cache.

Where: ``$LENSPAIR_CACHE_DIR/pair-stats`` when that is set, else
``$XDG_CACHE_HOME/lenspair/pair-stats``, else ``~/.cache/lenspair/pair-stats``
(off where there is no home folder); one small JSON file per measured pair
(about 4 KB), in a folder per code fingerprint: a build removes the folders of
other versions, which no key of its own finds, so an upgrade does not leave
the old entries on a robot's disk. ``LENSPAIR_CACHE_DIR=`` (set, empty) turns
the cache off. Deleting the folder is always safe. An entry that does not
read back (cut by a power loss, edited) is measured again and rewritten; a
cache folder that cannot be written is said once, and the build measures
without it. A pair whose files change while it is measured is not kept.
"""

import ast
import base64
import functools
import importlib.util
import json
import logging
import os
import shutil
import threading
from collections.abc import Iterator, Mapping
from dataclasses import fields
from pathlib import Path

import cv2
import numpy as np
import OpenImageIO as oiio

from lenspair import __version__
from lenspair.capture.journal import fingerprint
from lenspair.core.fsutil import atomic_write
from lenspair.dataset.curation import PairStats

logger = logging.getLogger(__name__)

CACHE_ENV = "LENSPAIR_CACHE_DIR"
"""Environment variable naming the cache folder (empty: no cache)."""
FORMAT = 1
"""Version of an entry's layout: bumped when :func:`_encode` changes."""
MEASURING_MODULES = ("lenspair.dataset.curation", "lenspair.core.imageio")
"""Where measuring starts; :func:`code_fingerprint` follows their lenspair imports."""
VERSION_DIGITS = 16
"""Hexadecimal digits of :func:`code_fingerprint` naming a version's folder."""
_FLOAT_FIELDS = tuple(f.name for f in fields(PairStats) if f.name != "thumbnail")


def cache_folder() -> Path | None:
    """The folder of pair figures (module docstring), or None where the cache is off."""
    chosen = os.environ.get(CACHE_ENV)
    if chosen is not None:
        return Path(chosen).expanduser() / "pair-stats" if chosen else None
    base = os.environ.get("XDG_CACHE_HOME")
    if not base:
        try:
            base = str(Path.home() / ".cache")
        except RuntimeError:  # no HOME, and a user id without a passwd entry (a container)
            logger.info("measurement cache off: no home folder (set %s)", CACHE_ENV)
            return None
    return Path(base) / "lenspair" / "pair-stats"


@functools.cache
def code_fingerprint() -> str:
    """A hash of what measuring a pair runs: lenspair's sources and the image libraries.

    The source of :data:`MEASURING_MODULES` and of every lenspair module they
    import, directly or not (found by reading the import statements, those
    inside functions too), with the versions of OpenCV, NumPy and
    OpenImageIO and of the decoders OpenImageIO uses. Editing any of those
    files, or upgrading a library, gives new keys: a cached figure never
    outlives the code that measured it.
    """
    sources = dict(_module_sources(MEASURING_MODULES))
    libraries = {
        "opencv": cv2.__version__,
        "numpy": np.__version__,
        "oiio": oiio.__version__,
        # the decoders OpenImageIO was built with (libjpeg-turbo, libpng): a shared build
        # can pick up another without OpenImageIO's own version changing
        "oiio_libraries": oiio.get_string_attribute("library_list"),
    }
    return fingerprint({"format": FORMAT, "modules": sources, "libraries": libraries})


def _module_sources(roots: tuple[str, ...]) -> Iterator[tuple[str, str]]:
    """``(module, sha256 of its source)`` for ``roots`` and the lenspair modules they import."""
    seen: set[str] = set()
    pending = list(roots)
    while pending:
        name = pending.pop()
        if name in seen:
            continue
        seen.add(name)
        spec = importlib.util.find_spec(name)
        if spec is None or spec.origin is None or not spec.origin.endswith(".py"):
            yield name, __version__  # no source to read (a frozen build): the version stands in
            continue
        text = Path(spec.origin).read_bytes()
        yield name, fingerprint(text.decode("utf-8", "replace"))
        pending.extend(_lenspair_imports(text, spec.submodule_search_locations is not None, name))


def _lenspair_imports(source: bytes, is_package: bool, name: str) -> Iterator[str]:
    """The lenspair modules a module's source imports (``from a import b``: ``a.b`` if a module)."""
    package = name if is_package else name.rpartition(".")[0]
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            yield from (a.name for a in node.names if a.name.split(".")[0] == "lenspair")
        elif isinstance(node, ast.ImportFrom):
            module = node.module or ""
            if node.level:  # relative: resolved against this module's package
                module = importlib.util.resolve_name("." * node.level + module, package)
            if module.split(".")[0] != "lenspair":
                continue
            yield module
            for alias in node.names:
                if _is_module(f"{module}.{alias.name}"):
                    yield f"{module}.{alias.name}"


def _is_module(name: str) -> bool:
    try:
        return importlib.util.find_spec(name) is not None
    except (ImportError, AttributeError, ValueError):  # a class or function of a module
        return False


class StatsCache:
    """Pair figures by key, one JSON file each under ``folder`` (module docstring)."""

    def __init__(self, folder: Path) -> None:
        """Use ``folder`` (created on the first write)."""
        self.folder = folder
        # here, before the build's threads: ast.parse from two threads at once raised
        # "SystemError: AST constructor recursion depth mismatch" (CPython 3.11)
        self.code = code_fingerprint()
        self.hits = 0
        self._lock = threading.Lock()
        self._off = False

    def key(self, hashes: Mapping[str, str], anomaly_delta: float) -> str:
        """The key of a pair: its files' SHA-256s by kind, the anomaly delta, the code."""
        return fingerprint(
            {"files": dict(hashes), "anomaly_delta": anomaly_delta, "code": self.code}
        )

    @property
    def version_folder(self) -> Path:
        """Where this code's entries live: one folder per :func:`code_fingerprint`."""
        return self.folder / self.code[:VERSION_DIGITS]

    def _path(self, key: str) -> Path:
        return self.version_folder / key[:2] / f"{key}.json"

    def prune(self) -> None:
        """Remove the entries of other code or library versions: no key of this one finds them.

        Only folders named as :attr:`version_folder` is (hexadecimal digits) are
        touched. A build of another version running meanwhile loses its entries
        and measures again.
        """
        try:
            others = [
                p
                for p in self.folder.iterdir()
                if p.is_dir()
                and p != self.version_folder
                and len(p.name) == VERSION_DIGITS
                and all(c in "0123456789abcdef" for c in p.name)
            ]
        except OSError:  # absent until the first write, or not listable: nothing to prune
            return
        for other in others:
            shutil.rmtree(other, ignore_errors=True)
        if others:
            logger.info(
                "measurement cache: removed the figures of %d earlier version(s) from %s",
                len(others),
                self.folder,
            )

    def get(self, key: str) -> PairStats | None:
        """The figures kept under ``key``; None when absent or not readable as figures."""
        if self._off:
            return None
        try:
            stats = _decode(self._path(key).read_text(encoding="utf-8"))
        except (OSError, ValueError, KeyError, TypeError):  # absent, cut short or edited
            return None
        with self._lock:
            self.hits += 1
        return stats

    def put(self, key: str, stats: PairStats) -> None:
        """Keep ``stats`` under ``key``; a folder that refuses turns the cache off, said once."""
        if self._off:
            return
        data = _encode(stats).encode("utf-8")

        def write(tmp: Path) -> None:
            tmp.write_bytes(data)

        try:
            # no fsync: an entry a power loss cuts short is measured again
            atomic_write(self._path(key), write, sync=False)
        except OSError as exc:
            with self._lock:
                if self._off:
                    return
                self._off = True
            why = exc.strerror or type(exc).__name__
            logger.warning(
                "measurement cache %s: cannot be written (%s); measuring without it "
                "(%s names another folder, or is set empty to turn it off)",
                self.folder,
                why,
                CACHE_ENV,
            )


def open_cache() -> StatsCache | None:
    """The user's cache (:func:`cache_folder`), or None where it is turned off."""
    folder = cache_folder()
    if folder is None:
        return None
    cache = StatsCache(folder)
    cache.prune()
    return cache


def _encode(stats: PairStats) -> str:
    """``stats`` as JSON: floats as Python writes them (exact), the thumbnail's float32 bytes."""
    thumbnail = np.ascontiguousarray(stats.thumbnail, dtype="<f4")
    entry: dict[str, object] = {name: float(getattr(stats, name)) for name in _FLOAT_FIELDS}
    entry["thumbnail"] = {
        "shape": list(thumbnail.shape),
        "float32_le": base64.b64encode(thumbnail.tobytes()).decode("ascii"),
    }
    return json.dumps(entry, sort_keys=True)


def _decode(text: str) -> PairStats:
    """What :func:`_encode` wrote; ValueError, KeyError or TypeError on anything else."""
    entry = json.loads(text)
    values = {name: entry[name] for name in _FLOAT_FIELDS}
    if not all(type(value) is float for value in values.values()):
        raise TypeError("a figure is not a float")
    shape = tuple(entry["thumbnail"]["shape"])
    raw = base64.b64decode(entry["thumbnail"]["float32_le"], validate=True)
    thumbnail = np.frombuffer(raw, dtype="<f4").reshape(shape).astype(np.float32)
    return PairStats(**values, thumbnail=thumbnail)

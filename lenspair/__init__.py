"""lenspair: paired camera-anomaly datasets and fast anomaly mitigation.

One import name for the whole toolkit. The stages are sub-packages
(``lenspair.capture``, ``lenspair.rectify``, ``lenspair.dataset``,
``lenspair.model``, ``lenspair.simulate``; in the repository they are the
top-level folders of the same names); :mod:`lenspair.core` holds the helpers
they share (errors, typed config loader, image I/O, atomic writes, progress
bars, reports) and imports no stage; :mod:`lenspair.cli`,
:mod:`lenspair.commands` and :mod:`lenspair.demo` are the face.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("lenspair")
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0.0.0+local"

__all__ = ["__version__"]

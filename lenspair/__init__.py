"""lenspair: paired camera-anomaly datasets and fast anomaly mitigation.

The stage packages live beside this one at the repository root
(``capture``, ``rectify``, ``dataset``, ``model``, ``simulate``); this package
holds what they share: errors, the typed config loader, image I/O, atomic
file writes, progress bars and the command-line interface.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("lenspair")
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0.0.0+local"

__all__ = ["__version__"]

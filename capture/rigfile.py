"""``rig.yaml``: which camera of a recording is obstructed, by what, and its calibration.

Example::

    obstructed: cam1          # cam0 or cam1: the camera behind the dirty glass
    anomaly: [rain]           # rain, dust, dirt, ... (free labels, lower case)
    calibration: camchain.yaml  # optional; relative to rig.yaml

The ground-truth (clean) side is the other camera. It is swapped between
sessions on real rigs, so it is read per recording, never assumed.
"""

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from lenspair.core.config import dump_yaml, load_yaml
from lenspair.core.fsutil import atomic_write_text

CameraName = Literal["cam0", "cam1"]
RIG_FILE = "rig.yaml"


@dataclass(frozen=True)
class RigFile:
    """Contents of ``rig.yaml``.

    Attributes:
        obstructed: the camera that looks through the glass with the anomaly.
        anomaly: anomaly labels, e.g. ``("rain",)``.
        calibration: calibration file, relative to the folder holding rig.yaml.
    """

    obstructed: CameraName
    anomaly: tuple[str, ...] = ()
    calibration: str | None = None

    @property
    def clean(self) -> CameraName:
        """The ground-truth camera (the one that is not obstructed)."""
        return "cam0" if self.obstructed == "cam1" else "cam1"


def read_rig_file(path: Path) -> RigFile:
    """Load ``rig.yaml``; errors name the file and the key (``ConfigError``)."""
    return load_yaml(RigFile, Path(path))


def write_rig_file(path: Path, rig: RigFile) -> None:
    """Write ``rig.yaml`` atomically."""
    atomic_write_text(Path(path), dump_yaml(rig))

"""``rig.yaml``: which camera of a recording is obstructed, by what, and its calibration.

Example::

    obstructed: cam1          # cam0 or cam1: the camera behind the dirty glass (optional
                              # when --obstructed names it)
    anomaly: [rain]           # rain, dust, dirt, ... (free labels, lower case)
    calibration: camchain.yaml  # optional; relative to rig.yaml

The ground-truth (clean) side is the other camera. It is swapped between
sessions on real rigs, so it is read per recording, never assumed.
"""

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from lenspair.core.config import dump_yaml, load_dataclass, read_yaml
from lenspair.core.errors import ConfigError
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


def read_rig_file(path: Path, obstructed: CameraName | None = None) -> RigFile:
    """Load ``rig.yaml``; errors name the file and the key (``ConfigError``).

    Args:
        path: the file.
        obstructed: the camera ``--obstructed`` names, which wins over the
            file's: then ``obstructed`` may be left out of the file (its
            labels and calibration are still read). Without it, a file that
            leaves it out is refused.
    """
    path = Path(path)
    data = read_yaml(path)
    if obstructed is not None and (data is None or isinstance(data, dict)):
        data = {"obstructed": obstructed, **(data or {})}
    try:
        return load_dataclass(RigFile, data)
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None


def write_rig_file(path: Path, rig: RigFile) -> None:
    """Write ``rig.yaml`` atomically."""
    atomic_write_text(Path(path), dump_yaml(rig))

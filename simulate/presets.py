"""Synthetic-drop presets and clean-image discovery, importable without torch.

``ours`` is the paper's kind of drop (out of focus, brighter, with the veil of
wet glass), ``sharp`` is Porav et al.'s reference. Synthetic pretraining
(:mod:`lenspair.model.training.synthetic`), ``lenspair realism`` and the
detector's synthetic data all draw from here.
"""

from pathlib import Path

from lenspair.capture.folders import IMAGE_SUFFIXES
from lenspair.simulate.effects.spec import (
    SHARP_DROPS,
    BrightnessSpec,
    DefocusSpec,
    EffectsSpec,
    RaindropsSpec,
    VeilSpec,
)
from lenspair.simulate.errors import SimulateError

CLEAN_FOLDER_NAMES = ("target", "gt", "clean", "clear")
"""Folders of clean images: a dataset's targets, Raindrop's ground truth, a simulated
recording's ``truth/clear`` (beside its obstructed camera's frames and its masks)."""

OUR_DROPS = EffectsSpec(
    raindrops=RaindropsSpec(
        count=250,
        radius_px=(3.0, 60.0),
        size_distribution="power-law",
        size_exponent=2.0,
        contact_angle_deg=(20.0, 60.0),
    ),
    defocus=DefocusSpec(),
    brightness=BrightnessSpec(fraction=0.6, gain=(1.2, 2.0)),
    veil=VeilSpec(strength=(0.1, 0.25), level=(1.1, 1.6)),
)
"""Our synthetic drops, tuned to look like real adherent drops (issue 12).

Many small drops and a few large merged ones (power-law radii, 3-60 px),
flatter than hemispheres; the glass 3 cm in front of an Alphasense-like
camera (2.4 mm f/2.0, so a 14 px blur disk, the paper's averaged shifts);
most drops brightened; a veil of scattered light over the whole frame.
Over the bundled natural images at 720x480 every statistic of
:mod:`lenspair.simulate.realism` overlaps the real range
(``lenspair realism --render ours sharp`` prints them).
"""

DROPS_PRESETS: dict[str, EffectsSpec] = {"ours": OUR_DROPS, "sharp": SHARP_DROPS}
"""Synthetic-drop presets by name (``--drops``)."""


def drops_preset(name: str) -> EffectsSpec:
    """The effects of a synthetic-drop preset; unknown names list the valid ones."""
    try:
        return DROPS_PRESETS[name]
    except KeyError:
        valid = ", ".join(DROPS_PRESETS)
        raise SimulateError(f"unknown drops preset {name!r}; valid presets: {valid}") from None


MACOS_ARCHIVE_FOLDER = "__MACOSX"
"""What a zip made on macOS unpacks beside its files: AppleDouble ``._<name>`` resource
forks, binary, named like the images they belong to."""


def _visible(path: Path, root: Path) -> bool:
    """Whether ``path`` is a file a user put under ``root``: no hidden part, no macOS fork.

    ``._0_clean.png`` and ``__MACOSX/gt/._0_clean.png`` (a Raindrop zip unpacked on
    macOS) were read as images and refused the whole folder; ``.DS_Store`` and hidden
    folders are passed over as the paired readers and ``restore`` pass them over.
    """
    parts = path.relative_to(root).parts
    return not any(part.startswith(".") or part == MACOS_ARCHIVE_FOLDER for part in parts)


def find_clean_images(folder: Path) -> list[Path]:
    """Clean images under ``folder`` for synthetic pretraining, sorted.

    When the folder holds ``target/`` (or ``gt/``, ``clean/``, ``clear/``)
    sub-folders, as a lenspair dataset or a simulated recording does, only the
    images in them are used (for a dataset
    root, only those of ``train/``, so validation and test images stay
    unseen); otherwise every image below ``folder`` (the suffixes ``restore``
    and ``train`` read: :data:`lenspair.capture.folders.IMAGE_SUFFIXES`).
    Hidden files and folders and macOS's ``__MACOSX`` are passed over.

    Raises:
        SimulateError: no image found.

    """
    folder = Path(folder)
    if not folder.is_dir():
        raise SimulateError(f"{folder}: not a folder of clean images")
    if (folder / "train").is_dir() and any(
        (folder / "train" / name).is_dir() for name in CLEAN_FOLDER_NAMES
    ):
        folder = folder / "train"  # a dataset root: never pretrain on val/test targets
    images = sorted(
        p
        for p in folder.rglob("*")
        if p.suffix.lower() in IMAGE_SUFFIXES and _visible(p, folder) and p.is_file()
    )
    clean = [p for p in images if p.parent.name.lower() in CLEAN_FOLDER_NAMES]
    chosen = clean or images
    if not chosen:
        raise SimulateError(
            f"{folder}: no images found (reads {', '.join(sorted(IMAGE_SUFFIXES))})"
        )
    return chosen

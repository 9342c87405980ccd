"""Curate ingested recordings into a paired train/val/test dataset, or verify one.

  lenspair dataset-build OUT/rec_a OUT/rec_b --out DS [--splits 0.8,0.1,0.1] [--seed 0]
                         [--config curation.yaml] [--overwrite] [--previous DS_OLD]
  lenspair dataset-build --verify DS

Curation removes, in this order and counting each: pairs rejected at ingest,
pairs whose images are missing, corrupt or fail their sha256, poor
registration (residual, photometric residual, inliers, mask fraction),
motion blur (sharpness of the clean view), bad exposure, with clean_pairs:
exclude pairs without a visible anomaly (by default they are kept and tagged
difficulty "clean"), and near-duplicate frames (robot standing still; the
frame that stands for a run is one that passed every rule above).
Kept pairs are tagged easy (PSNR > 25 dB), medium or hard (< 20 dB).

Pairs are split by recording (or, with few recordings, by contiguous segment
with a gap at the borders) via a seeded hash, and every split sees both
ground-truth sides when the data allows. Adding a recording later leaves
hashed pairs where they were (a side that now has groups enough for every
split is filled from the new recordings, or left short with a warning);
groups moved to fill a split (for the sides, or an empty train; named in
dataset.json) can move back, and a rebuild warns with the count of pairs
that changed split against the dataset it replaces. To get the same when
building a new version into another folder, pass the old one as --previous
DS_OLD. One session cut into several recordings (rosbag record --split) is
several groups, and the build warns when a join between them falls between
two splits: ingest such a session as one recording (a ROS 2 bag
folder is one; merge split ROS 1 bags into one .bag first).

Output: DS/{train,val,test}/{input,target[,mask]}/<rec>_<t_ns>.png,
manifest.jsonl, dataset.json (the card), removed.jsonl (each removed pair
with its rule and reason), config.yaml and contact_<split>.png. Same inputs
and seed give byte-identical files (the count of pairs a rebuild moved is
printed, not written into dataset.json). One thing carries over: with
group_by auto, a build that extends DS (shares a recording with it) keeps
DS's grouping, so that adding recordings does not reshuffle its splits
(config.yaml names the grouping kept); an unrelated DS hands on nothing.

Images are independent copies of the ingested ones (a reflink where the file
system supports it, else a byte copy): editing a dataset image never changes
the recording or another dataset. --link hard saves the space with hard
links instead, makes those files read-only and says so in dataset.json.
A killed build leaves nothing the next build of the same DS does not remove.

DS is written beside its final place and renamed into it, so it cannot be a
mount point (a Docker volume, a mounted disk): give a folder inside one.

--verify re-checks every file against the manifest, and the card's counts,
pairs_in and per-rule removed counts against the manifest and removed.jsonl,
its configuration (seed included) against config.yaml, and exits with status 1
and a list of problems when anything is off (also a missing removed.jsonl or
config.yaml, and a file in an input/, target/ or mask/ folder that the manifest
does not list, in a split or not). Files you add elsewhere in DS (notes,
train/restored/...) are yours: a rebuild keeps them, with a warning.
"""

import argparse
from pathlib import Path

from lenspair.commands.argtypes import (
    float_at_least,
    input_path,
    out_folder,
    random_seed,
    worker_count,
)
from lenspair.core.errors import ConfigError
from lenspair.dataset.build import build_dataset
from lenspair.dataset.config import SPLITS, load_dataset_config, parse_fractions, with_overrides
from lenspair.dataset.curation import RULE_NAMES
from lenspair.dataset.verify import verify_dataset

DATASET_ARGUMENTS = ("verify",)
"""Arguments naming datasets this command reads (``--verify``): ``lenspair.cli`` holds their
locks meanwhile (a build itself takes its --out's lock exclusively, for the swap)."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the arguments of ``dataset-build``."""
    parser.add_argument("sources", nargs="*", type=input_path, help="ingested recording folders")
    parser.add_argument("--out", type=out_folder, help="dataset folder to create")
    parser.add_argument("--verify", type=input_path, metavar="DS", help="check an existing dataset")
    parser.add_argument("--splits", help="train,val,test fractions of groups (0.8,0.1,0.1)")
    parser.add_argument("--seed", type=random_seed, help="split seed (default 0)")
    parser.add_argument("--config", type=input_path, help="YAML with curation: and split: sections")
    parser.add_argument("--overwrite", action="store_true", help="replace a different dataset")
    parser.add_argument(
        "--previous",
        type=input_path,
        metavar="DS_OLD",
        help="an earlier version of this dataset in another folder (DS_v1 when building "
        "DS_v2): its grouping and hashed splits are kept, as a rebuild in place keeps DS's, "
        "and the pairs that changed split against it are said",
    )
    parser.add_argument(
        "--accept-side-mismatch",
        action="store_true",
        help="build recordings whose images capture-ingest's detector (--detector) found to "
        "contradict the declared obstructed camera with confidence >= 0.5 (report.json "
        "side_check) as declared; refused by default (other mismatches only warn)",
    )
    parser.add_argument(
        "--link",
        choices=("copy", "hard"),
        help="copy: images independent of the ingested ones (reflink where the file system "
        "can, else a copy; default); hard: hard links, read-only, noted in the card",
    )
    parser.add_argument(
        "--workers", type=worker_count, help="threads reading images (default up to 4)"
    )
    group = parser.add_argument_group("common thresholds (override --config)")
    group.add_argument(
        "--max-residual-px", type=float_at_least(0.0), help="registration residual (2.0)"
    )
    group.add_argument(
        "--min-sharpness", type=float_at_least(0.0), help="variance of Laplacian (20)"
    )
    group.add_argument(
        "--duplicate-threshold", type=float_at_least(0.0), help="thumbnail difference (0.004)"
    )
    group.add_argument(
        "--exclude-clean", action="store_true", help="drop pairs without visible anomaly"
    )
    group.add_argument(
        "--group-by", choices=("auto", "recording", "segment"), help="split groups (auto)"
    )


BUILD_ONLY = {
    "out": "--out",
    "splits": "--splits",
    "seed": "--seed",
    "config": "--config",
    "overwrite": "--overwrite",
    "previous": "--previous",
    "accept_side_mismatch": "--accept-side-mismatch",
    "max_residual_px": "--max-residual-px",
    "min_sharpness": "--min-sharpness",
    "duplicate_threshold": "--duplicate-threshold",
    "exclude_clean": "--exclude-clean",
    "group_by": "--group-by",
    "link": "--link",
}
"""Options of a build, by ``argparse`` dest: none means anything to ``--verify``."""


def _given(value: object) -> bool:
    return value is not None and value is not False


def run(args: argparse.Namespace) -> int:
    """Build (or verify) a dataset; returns the exit code."""
    if args.verify is not None:
        # 0 == False: a --seed 0 or a zero threshold is given all the same
        given = [flag for dest, flag in BUILD_ONLY.items() if _given(getattr(args, dest))]
        given += ["recording folders"] if args.sources else []
        if given:
            # checked against its own config.yaml and seed: a --seed or --splits given here
            # was ignored, and "OK" read as the dataset checked against them
            raise ConfigError(
                f"--verify takes only the dataset folder (and --workers): {', '.join(given)} "
                "would change nothing it checks; it checks DS against the config and seed "
                "it was built with"
            )
        return _verify(args.verify, args.workers)
    if not args.sources or args.out is None:
        raise ConfigError("give ingested recording folders and --out DS (or --verify DS)")
    config = load_dataset_config(args.config)
    try:
        fractions = parse_fractions(args.splits) if args.splits is not None else None
    except ValueError as exc:
        raise ConfigError(f"--splits: {exc}") from None
    try:
        config = with_overrides(
            config,
            curation={
                "max_residual_px": args.max_residual_px,
                "min_sharpness": args.min_sharpness,
                "duplicate_threshold": args.duplicate_threshold,
                "clean_pairs": "exclude" if args.exclude_clean else None,
            },
            split={"fractions": fractions, "seed": args.seed, "group_by": args.group_by},
        )
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    result = build_dataset(
        args.sources,
        args.out,
        config,
        overwrite=args.overwrite,
        workers=args.workers,
        link=args.link or "copy",
        accept_side_mismatch=args.accept_side_mismatch,
        previous=args.previous,
    )
    card = result.card
    print(f"dataset written to {result.out}: {card.counts['all'].pairs} of {card.pairs_in} pairs")
    for name in SPLITS:
        counts = card.counts[name]
        sides = ", ".join(f"{side} {n}" for side, n in counts.clean_side.items())
        levels = ", ".join(f"{level} {n}" for level, n in counts.difficulty.items() if n)
        print(f"  {name:5s} {counts.pairs:6d} pairs, {counts.groups} groups; clean side {sides}")
        if levels:
            print(f"        {levels}")
    removed = {rule.rule: rule.removed for rule in card.curation}
    listed = ", ".join(f"{r} {removed[r]}" for r in RULE_NAMES if removed[r])
    print(f"  removed: {listed or 'none'}; tagged clean (kept): {card.tagged_clean}")
    for warning in card.grouping.warnings:
        print(f"  warning: {warning}")
    if result.changed_splits:
        print(f"  warning: {result.changed_splits}")
    wanted = dict(zip(SPLITS, card.fractions, strict=True))
    for name in ("val", "test"):
        if wanted[name] > 0 and card.counts[name].pairs == 0:
            print(
                f"  note: split {name!r} is empty (too few recordings or segments): "
                + (
                    "train holds out a tenth of train/ to validate"
                    if name == "val"
                    else "eval needs another --split; add recordings to fill it"
                )
            )
    return 0


def _verify(root: Path, workers: int | None) -> int:
    result = verify_dataset(root, workers=workers)
    if result.ok:
        print(f"{root}: OK ({result.pairs} pairs, {result.files} files checked)")
        return 0
    print(f"{root}: {len(result.problems)} problem(s):")
    for problem in result.problems:
        print(f"  {problem}")
    return 1

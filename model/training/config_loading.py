"""Loading run configurations, layering one on another, and saying what changed.

A run's configuration (:class:`~lenspair.model.training.config.RunConfig`)
comes from a user's ``--config`` YAML file (:func:`load_run_config`), from a
run's own ``config.yaml`` or checkpoint (:func:`stored_run_config`, which
reads keys added since with the values runs had before them:
:data:`EARLIER_DEFAULTS`), or from a ``--config`` laid over another
configuration (:func:`with_file`). :func:`config_differences` lists the keys
in which two configurations differ, as ``train --resume`` and ``tradeoff``
report them.
"""

import dataclasses
import logging
from pathlib import Path
from typing import Any

from lenspair.core.config import load_dataclass, read_yaml, to_plain
from lenspair.core.errors import ConfigError
from lenspair.model.training.config import DataConfig, RunConfig, RuntimeInfo

log = logging.getLogger(__name__)


def load_run_config(path: Path | None, given: bool = False, stored: bool = False) -> RunConfig:
    """Read a run configuration YAML file; ``None`` gives the defaults.

    ``given``: the user's ``--config``; a ``runtime`` section in it (a run's
    ``config.yaml``, reused) is said to steer nothing. ``stored``: a run's
    own ``config.yaml``, read as :func:`stored_run_config` does.

    Raises:
        ConfigError: unknown key, wrong type or invalid value (dotted path named).

    """
    if path is None:
        return RunConfig()
    data = read_yaml(path)  # its errors name the file already
    # a user's paths are read beside the file, as absolute ones: the run's config.yaml
    # keeps them, and a resume from another folder finds the same file
    base_dir = None if stored else Path(path).resolve().parent
    try:
        config = stored_run_config(data) if stored else run_config_from_dict(data, base_dir)
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None
    if given and config.runtime is not None:  # a run's config.yaml, reused: nothing steers
        log.info(
            "%s: its runtime section records what a run did and is not read as settings "
            "(precision, device and init are train.precision, --device and --init)",
            path,
        )
    return config


def with_file(config: RunConfig, path: Path) -> RunConfig:
    """``config`` with the keys the file ``path`` names set from it; every other key kept.

    For a ``--config`` given on top of a configuration that is not the
    defaults (the stored one of ``train --resume``, ``tradeoff``'s own): a
    file written to set, say, ``train.patience`` changes that, and no more.

    Raises:
        ConfigError: the file alone is invalid (named, as :func:`load_run_config`),
            or the combination is.
    """
    # its own keys and types, with the file named; its paths read beside it, while the
    # stored configuration's keep what they were (re-read beside this file, a run's own
    # relative vgg19_weights moved into the folder of a file that only set patience)
    named = to_plain(load_run_config(path, given=True))
    data = read_yaml(path) or {}
    merged = to_plain(config)
    for section, values in data.items():
        if values is None:  # every key commented out: an empty section, as load_dataclass reads
            continue
        if isinstance(values, dict) and isinstance(merged.get(section), dict):
            merged[section] = {**merged[section], **{key: named[section][key] for key in values}}
        else:
            merged[section] = named.get(section, values)
    try:
        return run_config_from_dict(merged)
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None


def run_config_from_dict(data: object, base_dir: Path | None = None) -> RunConfig:
    """Build a :class:`RunConfig` from plain data (e.g. stored in a checkpoint).

    ``base_dir``: the folder of the YAML file ``data`` came from; a relative
    path in it (``train.vgg19_weights``) is read beside that file.

    The ``runtime`` section says what a run did and steers nothing: keys that
    a later lenspair added to it are passed over, so that a checkpoint or
    ``config.yaml`` written by a newer version still loads (a table of runs
    trained by a newer lenspair failed to score every one of them). The
    other sections stay strict: a typo there changes what trains.
    """
    if isinstance(data, dict) and isinstance(data.get("runtime"), dict):
        known = {f.name for f in dataclasses.fields(RuntimeInfo)}
        data = {**data, "runtime": {k: v for k, v in data["runtime"].items() if k in known}}
    return load_dataclass(RunConfig, data, base_dir=base_dir)


EARLIER_DEFAULTS: dict[tuple[str, str], object] = {("data", "clear_share"): 0.0}
"""Keys added later whose default changes what trains: ``(section, key)`` -> what runs did before.

A configuration a run stored before the key existed (its checkpoint, its
``config.yaml``) is read with this value, not today's default, so that
``train --resume`` goes on as the run began, and a ``--config`` that sets
today's default is reported as the change it is.
"""


def stored_run_config(data: object) -> RunConfig:
    """:func:`run_config_from_dict` for a configuration a run stored (:data:`EARLIER_DEFAULTS`).

    A run stored before ``data.val_split`` had to differ from ``data.train_split``
    (it validated on its training pairs) is read with the default ``val_split``
    and a warning: its network still restores and scores, and a resume
    validates on pairs it does not train on.
    """
    if isinstance(data, dict):
        for (section, key), value in EARLIER_DEFAULTS.items():
            part = data.get(section)
            if isinstance(part, dict) and key not in part:
                data = {**data, section: {**part, key: value}}
        data = _validation_apart(data)
    return run_config_from_dict(data)


def _validation_apart(data: dict[str, Any]) -> dict[str, Any]:
    """``data`` with the default ``data.val_split`` when it stored the training split's."""
    part = data.get("data")
    default = DataConfig()
    if not isinstance(part, dict):
        return data
    train = part.get("train_split", default.train_split)
    if part.get("val_split", default.val_split) != train or train == default.val_split:
        return data
    log.warning(
        "a run's stored config validated on its training split %r (data.val_split): read "
        "with val_split %r",
        train,
        default.val_split,
    )
    return {**data, "data": {**part, "val_split": default.val_split}}


def field_differences(old: Any, new: Any) -> list[tuple[str, Any, Any]]:
    """``(field, old value, new value)`` of each field that differs between two sections."""
    return [
        (f.name, getattr(old, f.name), getattr(new, f.name))
        for f in dataclasses.fields(old)
        if getattr(old, f.name) != getattr(new, f.name)
    ]


def config_differences(old: RunConfig, new: RunConfig) -> list[str]:
    """Dotted keys whose values differ between two configs (``runtime`` ignored)."""
    return [
        f"{section}.{name}: {before!r} -> {after!r}"
        for section in ("model", "data", "train", "loss")
        for name, before, after in field_differences(getattr(old, section), getattr(new, section))
    ]

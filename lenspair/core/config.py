"""Typed configuration: YAML files into frozen dataclasses, strictly.

One loader serves every config and spec in lenspair (scene specs, rig files,
curation thresholds, training configs). It rejects unknown keys and wrong
types with the dotted path of the offending key, so that a typo never
silently becomes a default::

    train.lr: expected float, got 'le-4'
    scene.planes[1].depth_m: unknown key 'depth'; valid keys: depth_m, texture

Supported field types: ``bool``, ``int``, ``float`` (ints accepted),
``str``, ``pathlib.Path``, ``Literal[...]``, ``X | None``, ``tuple[X, ...]``,
``tuple[X, Y]``, ``list[X]``, ``dict[str, X]`` and nested dataclasses. A
path is read as the file means it (:func:`config_path`): ``~`` is the home
folder, and a relative path is relative to the file's own folder.
"""

import contextlib
import dataclasses
import json
import math
import re
import types
import typing
from collections.abc import Iterable
from pathlib import Path
from typing import Any, Literal, TypeVar, Union, get_args, get_origin

import yaml

from lenspair.core.errors import ConfigError

T = TypeVar("T")

MAX_SEED = 2**32 - 1
"""Largest random seed an option or config takes (torch takes 64 bits, and
training derives its per-epoch seeds from ``train.seed``: they must fit)."""


def _type_name(tp: Any) -> str:
    if isinstance(tp, type):
        return tp.__name__
    return str(tp).replace("typing.", "")


def _describe(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def config_path(value: str | Path, base_dir: Path | None = None) -> Path:
    """A path written in a config file or spec, as the file means it.

    ``~`` is the user's home folder (YAML leaves it to the reader, as a shell
    would expand it), and a relative path is relative to ``base_dir``, the
    folder holding the file, so that a config reads the same whatever folder
    lenspair runs from. ``base_dir=None`` leaves a relative path as written.
    """
    path = Path(value)
    # ~nosuchuser, or no home folder: left as written, and "not found" names it
    with contextlib.suppress(RuntimeError):
        path = path.expanduser()
    return path if base_dir is None or path.is_absolute() else Path(base_dir) / path


def _convert(tp: Any, value: Any, path: str, base_dir: Path | None = None) -> Any:
    origin = get_origin(tp)
    args = get_args(tp)
    if tp is Any:
        return value
    if origin in (Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        options = [a for a in args if a is not type(None)]
        if len(options) == 1:  # X | None: the error inside X is the useful one
            return _convert(options[0], value, path, base_dir)
        for option in options:
            try:
                return _convert(option, value, path, base_dir)
            except ConfigError:
                continue
        expected = " or ".join(_type_name(a) for a in args)
        raise ConfigError(f"{path}: expected {expected}, got {_describe(value)}")
    if origin is Literal:
        if value in args:
            return value
        choices = ", ".join(repr(a) for a in args)
        raise ConfigError(f"{path}: expected one of {choices}, got {_describe(value)}")
    if dataclasses.is_dataclass(tp) and isinstance(tp, type):
        return load_dataclass(tp, value, path, base_dir)
    if tp is bool:
        if isinstance(value, bool):
            return value
        raise ConfigError(f"{path}: expected bool, got {_describe(value)}")
    if tp is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
        raise ConfigError(f"{path}: expected int, got {_describe(value)}")
    if tp is float:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            if not math.isfinite(value):
                raise ConfigError(f"{path}: expected a finite float, got {_describe(value)}")
            return float(value)
        raise ConfigError(f"{path}: expected float, got {_describe(value)}")
    if tp is str:
        if isinstance(value, str):
            return value
        raise ConfigError(f"{path}: expected str, got {_describe(value)}")
    if tp is Path:
        if isinstance(value, (str, Path)):
            return config_path(value, base_dir)
        raise ConfigError(f"{path}: expected a path, got {_describe(value)}")
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{path}: expected a list, got {_describe(value)}")
        if len(args) == 2 and args[1] is Ellipsis:
            items = enumerate(value)
            return tuple(_convert(args[0], v, f"{path}[{i}]", base_dir) for i, v in items)
        if len(value) != len(args):
            raise ConfigError(f"{path}: expected {len(args)} values, got {len(value)}")
        pairs = enumerate(zip(args, value, strict=True))
        return tuple(_convert(a, v, f"{path}[{i}]", base_dir) for i, (a, v) in pairs)
    if origin is list:
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{path}: expected a list, got {_describe(value)}")
        return [_convert(args[0], v, f"{path}[{i}]", base_dir) for i, v in enumerate(value)]
    if origin is dict:
        if not isinstance(value, dict):
            raise ConfigError(f"{path}: expected a mapping, got {_describe(value)}")
        key_type, value_type = args
        return {
            _convert(key_type, k, f"{path}.<key>", base_dir): _convert(
                value_type, v, f"{path}.{k}", base_dir
            )
            for k, v in value.items()
        }
    raise TypeError(f"config loader does not support type {tp!r} at {path}")


def load_dataclass(cls: type[T], data: Any, path: str = "", base_dir: Path | None = None) -> T:
    """Build dataclass ``cls`` from plain data (as parsed from YAML/JSON).

    Args:
        cls: a dataclass type; nested dataclass fields are built recursively.
        data: a mapping (``None`` is read as an empty mapping: a section
            written as a bare key, ``motion:``, takes its defaults). A field typed
            ``X | None`` stays ``None`` when its value is null: ``effects: {dust: }``
            leaves dust off (``lenspair.simulate.spec.load_scene`` warns of it).
        path: dotted prefix for error messages.
        base_dir: the folder of the file ``data`` was read from: a relative
            ``pathlib.Path`` field is read relative to it (:func:`config_path`;
            ``None``: as written). ``~`` is expanded either way.

    Raises:
        ConfigError: unknown key, missing required key, wrong type, or a
            ``__post_init__`` validation failure, with the dotted path.

    """
    prefix = f"{path}." if path else ""
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(f"{path or '<root>'}: expected a mapping, got {_describe(data)}")
    assert dataclasses.is_dataclass(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    hints = typing.get_type_hints(cls)
    unknown = sorted(set(map(str, data)) - set(fields))
    if unknown:
        valid = ", ".join(sorted(fields))
        raise ConfigError(f"{prefix}{unknown[0]}: unknown key; valid keys: {valid}")
    kwargs = {}
    for name, field in fields.items():
        if name in data:
            kwargs[name] = _convert(hints[name], data[name], f"{prefix}{name}", base_dir)
        elif field.default is dataclasses.MISSING and field.default_factory is dataclasses.MISSING:
            raise ConfigError(f"{prefix}{name}: required key is missing")
    try:
        return cls(**kwargs)
    except ConfigError:
        raise
    except (ValueError, TypeError) as exc:
        # a top-level check names its keys itself ("planes: ..."): no "<root>: " before it
        raise ConfigError(_under(path, str(exc), fields)) from None


def _under(path: str, message: str, fields: Iterable[str]) -> str:
    """A check's ``message`` placed under ``path``: a dotted key where it names its field.

    ``planes[0]`` and ``depth_m: expected ...`` give ``planes[0].depth_m: expected ...``;
    a message naming no single field of the dataclass follows ``path:``.
    """
    if not path:
        return message
    key = message.split(":", 1)[0]
    return f"{path}.{message}" if key in fields else f"{path}: {message}"


def text_lines(path: Path) -> list[tuple[int, str]]:
    """``(line number, text)`` of a UTF-8 text file (JSON lines), blank lines left out.

    Raises:
        ConfigError: a line that is not UTF-8, naming the file and the line
            (a whole-file decode gave a traceback and no line).
        FileNotFoundError: as ``open`` (callers say what the file should be).
    """
    lines = []
    for number, raw in enumerate(Path(path).read_bytes().splitlines(), start=1):
        try:
            line = raw.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise ConfigError(
                f"{path}:{number}: not UTF-8 text (byte {exc.start + 1}: {exc.reason})"
            ) from None
        if line.strip():
            lines.append((number, line))
    return lines


def read_json(path: Path) -> Any:
    """A JSON file's data.

    Raises:
        ConfigError: not UTF-8 text, or not valid JSON (names the file).
        FileNotFoundError: as ``open``.
    """
    try:
        return json.loads(Path(path).read_bytes().decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: not UTF-8 text (byte {exc.start + 1}: {exc.reason})") from None
    except json.JSONDecodeError as exc:
        raise ConfigError(f"{path}: not valid JSON ({exc})") from None


def read_yaml(file: Path) -> Any:
    """Parse a YAML file into plain data; every file problem is a one-line error.

    Raises:
        ConfigError: the file is missing, a folder, unreadable, not UTF-8 text,
            or not valid YAML; the message starts with the file name.

    """
    file = Path(file)
    try:
        text = file.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{file}: file not found") from None
    except IsADirectoryError:
        raise ConfigError(f"{file}: is a folder, expected a YAML file") from None
    except UnicodeDecodeError:
        raise ConfigError(f"{file}: not a text file (expected YAML)") from None
    except OSError as exc:
        raise ConfigError(f"{file}: cannot read ({exc.strerror or exc})") from None
    try:
        return yaml.load(text, Loader=_UniqueKeyLoader)  # a SafeLoader: plain data only
    except yaml.YAMLError as exc:
        raise ConfigError(f"{file}: not valid YAML ({_yaml_problem(exc)})") from None
    except RecursionError:  # PyYAML's composer recurses once per level
        raise ConfigError(f"{file}: not valid YAML (nested too deeply)") from None


def _yaml_problem(exc: yaml.YAMLError) -> str:
    """PyYAML's error in one line, where first: ``line 2, column 1: expected ','`` (and its start).

    Its message starts with the context ("while parsing a flow sequence"),
    which says neither what is wrong nor where.
    """
    mark = getattr(exc, "problem_mark", None)
    problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
    if mark is None:
        return str(problem)
    said = f"line {mark.line + 1}, column {mark.column + 1}: {problem}"
    start, context = getattr(exc, "context_mark", None), getattr(exc, "context", None)
    if start is None or not context or start.line == mark.line:
        return said
    # the mistake often lies where the context began (an unclosed quote, a key
    # without its colon), lines before the place PyYAML gave up
    return f"{said} ({context} begun at line {start.line + 1}, column {start.column + 1})"


_MERGE_TAG = "tag:yaml.org,2002:merge"
"""The tag of YAML's merge key ``<<``, which the loader flattens after the duplicate check."""


class _UniqueKeyLoader(yaml.SafeLoader):
    """PyYAML's safe loader, refusing a key given twice in one mapping.

    Plain ``safe_load`` keeps the last value: ``{raindrops: {count: 5},
    raindrops: {count: 0}}`` would render no drops without a word.

    It also reads ``1e-4``, ``4e-3`` and ``3.6e3`` as numbers, as YAML 1.2
    and every other YAML reader do: PyYAML follows YAML 1.1, where a float
    needs a dot and a signed exponent (``1.0e-4``, ``3.6e+3``), so ``lr: 1e-4``
    was the string ``'1e-4'`` and refused.
    """

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        seen: set[Any] = set()
        for key_node, _ in node.value:
            if key_node.tag == _MERGE_TAG:  # `<<: *base`: its keys may be given again here
                continue
            key = self.construct_object(key_node, deep=deep)  # type: ignore[no-untyped-call]
            if key in seen:
                raise yaml.constructor.ConstructorError(
                    None, None, f"key {key!r} given twice", key_node.start_mark
                )
            seen.add(key)
        return super().construct_mapping(node, deep=deep)


# YAML 1.2's exponent floats PyYAML (YAML 1.1: a dot and a signed exponent) reads as
# strings: 1e-4, 3.6e3, 1.e3, .5e3; its own float resolver takes the rest
_UniqueKeyLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9_]+)[eE][-+]?[0-9]+$"),
    list("-+0123456789."),
)


def load_yaml(cls: type[T], file: Path) -> T:
    """Load a YAML file into dataclass ``cls``; errors start with the file name.

    Path fields are read relative to the file's folder (:func:`config_path`).
    """
    file = Path(file)
    data = read_yaml(file)
    try:
        return load_dataclass(cls, data, base_dir=file.parent)
    except ConfigError as exc:
        raise ConfigError(f"{file}: {exc}") from None


def to_plain(obj: Any) -> Any:
    """Turn a (nested) dataclass into plain YAML/JSON-serialisable data."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: to_plain(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, (list, tuple)):
        return [to_plain(v) for v in obj]
    if isinstance(obj, dict):
        return {str(k): to_plain(v) for k, v in obj.items()}
    if isinstance(obj, Path):
        return str(obj)
    return obj


def dump_yaml(obj: Any) -> str:
    """Serialise a dataclass (or plain data) as YAML, keys in field order."""
    return yaml.safe_dump(to_plain(obj), sort_keys=False, default_flow_style=None)

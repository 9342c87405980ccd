from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import pytest

from lenspair.core.config import dump_yaml, load_dataclass, load_yaml, read_yaml
from lenspair.core.errors import ConfigError


@dataclass(frozen=True)
class Inner:
    depth_m: float
    texture: str = "brick"


@dataclass(frozen=True)
class Outer:
    lr: float = 2e-4
    epochs: int = 10
    mode: Literal["a", "b"] = "a"
    size: tuple[int, int] = (720, 540)
    planes: list[Inner] = field(default_factory=list)
    extra: Inner | None = None


def test_round_trip_through_yaml(tmp_path: Path) -> None:
    cfg = Outer(lr=1e-3, planes=[Inner(10.0), Inner(3.5, "grass")], extra=Inner(1.0))
    file = tmp_path / "c.yaml"
    file.write_text(dump_yaml(cfg))
    assert load_yaml(Outer, file) == cfg


@pytest.mark.parametrize(
    ("data", "message"),
    [
        ({"lr": "le-4"}, r"^lr: expected float, got 'le-4'$"),
        ({"epochs": 1.5}, r"^epochs: expected int"),
        ({"epochs": True}, r"^epochs: expected int"),
        ({"mode": "c"}, r"^mode: expected one of 'a', 'b'"),
        ({"size": [1, 2, 3]}, r"^size: expected 2 values, got 3"),
        ({"planes": [{"depth_m": 1}, {"depth": 2}]}, r"^planes\[1\]\.depth: unknown key"),
        ({"planes": [{"texture": "x"}]}, r"^planes\[0\]\.depth_m: required key is missing"),
        ({"lr": float("nan")}, r"^lr: expected a finite float"),
        ({"extra": {"depth_m": "far"}}, r"^extra\.depth_m: expected float, got 'far'$"),
        ({"lrr": 1.0}, r"^lrr: unknown key; valid keys: epochs, extra, lr, mode, planes, size"),
    ],
)
def test_errors_name_the_dotted_key(data: dict[str, object], message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        load_dataclass(Outer, data)


def test_int_is_accepted_for_float_and_none_enables_defaults() -> None:
    cfg = load_dataclass(Outer, {"lr": 1, "extra": {"depth_m": 2}})
    assert isinstance(cfg.lr, float)
    assert cfg.extra == Inner(2.0)
    assert load_dataclass(Outer, None) == Outer()


def test_yaml_file_errors_name_the_file(tmp_path: Path) -> None:
    file = tmp_path / "bad.yaml"
    file.write_text("lr: [1, 2\n")
    # where and what: it said "while parsing a flow sequence", neither
    with pytest.raises(
        ConfigError, match=r"bad\.yaml: not valid YAML \(line 2, column 1: expected ',' or ']'"
    ):
        load_yaml(Outer, file)
    # an unclosed quote on line 3 is found at the end of the file: both are named
    file.write_text("a: 1\nb: 2\nx: 'unterminated\n\n")
    with pytest.raises(
        ConfigError,
        match=r"line 5, column 1: found unexpected end of stream \(while scanning a quoted "
        r"scalar begun at line 3, column 4\)\)$",
    ):
        read_yaml(file)
    with pytest.raises(ConfigError, match=r"missing\.yaml: file not found"):
        load_yaml(Outer, tmp_path / "missing.yaml")
    deep = tmp_path / "deep.yaml"
    deep.write_text("seed: " + "[" * 2000 + "]" * 2000 + "\n")  # a RecursionError traceback
    with pytest.raises(ConfigError, match=r"deep\.yaml: not valid YAML \(nested too deeply\)"):
        read_yaml(deep)


def test_a_key_given_twice_is_refused_not_overwritten(tmp_path: Path) -> None:
    spec = tmp_path / "scene.yaml"
    spec.write_text("effects:\n  raindrops: {count: 5}\n  raindrops: {count: 0}\n")
    with pytest.raises(
        ConfigError, match=r"scene\.yaml: not valid YAML \(line 3, column 3: key 'raindrops' given"
    ):
        read_yaml(spec)


@pytest.mark.parametrize(
    ("text", "lr"),
    [("1e-4", 1e-4), ("4E-3", 4e-3), ("-2e+1", -20.0), ("3.6e3", 3600.0), ("1.e3", 1000.0),
     (".5e3", 500.0), ("1.5", 1.5), ("12", 12)],
)  # fmt: skip
def test_an_exponent_without_a_dot_is_a_number_as_in_yaml_1_2(
    tmp_path: Path, text: str, lr: float
) -> None:
    # PyYAML (YAML 1.1) read `lr: 1e-4` as the string '1e-4', and the config refused it
    file = tmp_path / "c.yaml"
    file.write_text(f"lr: {text}\nmode: b\n")
    assert load_yaml(Outer, file) == Outer(lr=lr, mode="b")
    file.write_text("epochs: 1e3\n")  # a float where an int goes is still refused
    with pytest.raises(ConfigError, match=r"epochs: expected int, got 1000\.0"):
        load_yaml(Outer, file)
    file.write_text("mode: 1e\n")  # not a number: stays a string (so do 1:2e3, e5)
    with pytest.raises(ConfigError, match=r"mode: expected one of 'a', 'b', got '1e'"):
        load_yaml(Outer, file)


@pytest.mark.parametrize("text", [None, "train: [1,\n", "train:\n  epochz: 3\n"])
def test_a_run_config_error_names_its_file_once(tmp_path: Path, text: str | None) -> None:
    from lenspair.model.training.config_loading import load_run_config

    path = tmp_path / "run.yaml"
    if text is not None:
        path.write_text(text)
    with pytest.raises(ConfigError) as caught:
        load_run_config(path)
    assert str(caught.value).startswith(f"{path}: ") and str(caught.value).count(str(path)) == 1


def test_yaml_merge_keys_are_read_and_their_keys_may_be_given_again(tmp_path: Path) -> None:
    """``<<: *base`` is valid YAML that safe_load reads; it was refused as an unknown tag."""
    path = tmp_path / "rig.yaml"
    path.write_text("cam0: &c {fx: 60.0, gain: 1.0}\ncam1: {<<: *c, gain: 1.04}\n")
    cam0 = {"fx": 60.0, "gain": 1.0}
    assert read_yaml(path) == {"cam0": cam0, "cam1": {**cam0, "gain": 1.04}}
    path.write_text("cam1: {<<: {fx: 1.0}, gain: 1.0, gain: 2.0}\n")  # own keys twice: refused
    with pytest.raises(ConfigError, match="key 'gain' given twice"):
        read_yaml(path)

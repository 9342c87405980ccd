"""resolve_device: every way of naming a device ends in a usable one or a one-line error."""

from pathlib import Path

import pytest
import torch

from lenspair.core.device import resolve_device
from lenspair.core.errors import LenspairError
from lenspair.model.inference.restorer import Restorer
from tests.model.train_fixtures import make_checkpoint


@pytest.fixture
def no_cuda(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)


@pytest.fixture
def two_gpus(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 2)


@pytest.mark.parametrize(
    "choice", ["cuda", "cuda:0", torch.device("cuda"), torch.device("cuda", 1)]
)
def test_cuda_on_a_machine_without_one_is_a_one_line_error(no_cuda: None, choice: object) -> None:
    with pytest.raises(LenspairError, match="no CUDA device is available"):
        resolve_device(choice)  # type: ignore[arg-type]


def test_auto_and_cpu_without_cuda(no_cuda: None) -> None:
    assert resolve_device("auto") == torch.device("cpu")
    assert resolve_device(torch.device("cpu")) == torch.device("cpu")
    assert resolve_device(torch.device("cpu", 0)) == torch.device("cpu")  # said "cpu:0"


def test_a_detector_asked_onto_a_missing_gpu_is_a_one_line_error(
    no_cuda: None, tmp_path: Path
) -> None:
    # load_detector handed the device to torch: "Torch not compiled with CUDA enabled"
    from lenspair.model.detection.train import load_detector  # the detector's own tests own it

    with pytest.raises(LenspairError, match="no CUDA device is available"):
        load_detector(Path("detector.pt"), "cuda")


def test_a_gpu_is_named_by_index_and_one_beyond_the_machine_s_is_refused(two_gpus: None) -> None:
    assert resolve_device("cuda:1") == torch.device("cuda", 1)
    assert resolve_device(torch.device("cuda", 0)) == torch.device("cuda", 0)
    assert resolve_device("auto") == torch.device("cuda")
    with pytest.raises(LenspairError, match=r"has 2 CUDA device\(s\), cuda:0 to cuda:1"):
        resolve_device("cuda:2")


@pytest.mark.parametrize("choice", ["gpu", "cuda:x", "cuda:", "mps", ""])
def test_unknown_names_are_refused(choice: str) -> None:
    with pytest.raises(LenspairError, match="expected auto, cpu or cuda"):
        resolve_device(choice)


def test_restorer_checks_a_torch_device_as_it_checks_a_name(
    no_cuda: None, tmp_path: Path, one_thread: None
) -> None:
    """A library caller's torch.device went past the check to torch's own assertion."""
    checkpoint = make_checkpoint(tmp_path / "ck.pt")
    with pytest.raises(LenspairError, match="no CUDA device is available"):
        Restorer(checkpoint, device=torch.device("cuda"))
    assert Restorer(checkpoint, device=torch.device("cpu"), precision="fp32").channels == 1

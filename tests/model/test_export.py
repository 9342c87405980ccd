import json
import logging
import os
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from lenspair.cli import main
from lenspair.model.checkpoint import load_model
from lenspair.model.detection.train import save_detector
from lenspair.model.errors import ModelError
from lenspair.model.evaluation.export import check_image, export_torchscript
from lenspair.model.evaluation.quantize import QUANTISED_OPS, open_session
from lenspair.model.inference.backends import OnnxBackend, open_backend
from lenspair.model.networks.detector import AnomalyDetector, DetectorSpec
from lenspair.model.networks.layers import InstanceNorm
from lenspair.model.training.pretrained import pretrained_weights
from tests.file_limits import REFUSALS, refuse_writes
from tests.model.train_fixtures import make_checkpoint, write_paired_folder
from tests.processes import dead_pid

pytestmark = pytest.mark.usefixtures("one_thread")


def test_onnx_export_matches_torch(tmp_path: Path) -> None:
    pytest.importorskip("onnx")
    ort = pytest.importorskip("onnxruntime")
    checkpoint = make_checkpoint(tmp_path / "c.pt")
    onnx_file = tmp_path / "model.onnx"
    script_file = tmp_path / "model.pt"
    args = ["export", str(checkpoint), "--onnx", str(onnx_file), "--torchscript", str(script_file)]
    assert main([*args, "--size", "48x32"]) == 0
    report = json.loads((tmp_path / "model.onnx.export.json").read_text())
    onnx_check, script_check = report["exports"]
    assert onnx_check["max_abs_diff"] < 1e-4
    assert onnx_check["runtime_median_ms"] > 0 and onnx_check["size"] == "48x32"
    assert script_check["max_abs_diff"] < 1e-4

    # Independently: onnxruntime on a fresh image, batch of two, against torch.
    network = load_model(checkpoint).network
    image = torch.rand(2, 1, 32, 48, generator=torch.Generator().manual_seed(5))
    session = ort.InferenceSession(str(onnx_file), providers=["CPUExecutionProvider"])
    (restored,) = session.run(None, {"image": image.numpy()})
    with torch.no_grad():
        expected = network(image)[1].numpy()
    assert restored.shape == (2, 1, 32, 48)
    assert np.abs(restored - expected).max() < 1e-4
    # Each instance norm is ONNX's own InstanceNormalization (a group norm would
    # export as reshapes around it plus a scale and a shift).
    onnx = pytest.importorskip("onnx")
    nodes = list(onnx.load(str(onnx_file)).graph.node)
    kinds = [node.op_type for node in nodes]
    norms = sum(isinstance(m, InstanceNorm) for m in network.modules())
    assert norms > 0 and kinds.count("InstanceNormalization") == norms
    # ... and nothing of a group norm's export is left: the only shapes taken are the
    # image's (H and W are dynamic: padding to a multiple of 4 and cropping back), and
    # each norm's output is scaled once, by the flat-frame mask
    # (lenspair.model.networks.layers), and read by nothing else
    assert "GroupNormalization" not in kinds
    assert {tuple(n.input) for n in nodes if n.op_type == "Shape"} == {("image",)}
    normalised = {n.output[0] for n in nodes if n.op_type == "InstanceNormalization"}
    readers = [n.op_type for n in nodes for name in n.input if name in normalised]
    assert readers == ["Mul"] * norms


def test_two_onnx_exports_of_a_checkpoint_are_the_same_bytes_and_name_no_path(
    tmp_path: Path,
) -> None:
    """The dynamo exporter noted stack traces (this machine's absolute paths) and memory
    addresses on every node: each export differed, and shipped the build machine's layout."""
    pytest.importorskip("onnx")
    pytest.importorskip("onnxruntime")
    checkpoint = make_checkpoint(tmp_path / "c.pt")
    exported = []
    for name in ("a.onnx", "b.onnx"):
        args = ["export", str(checkpoint), "--onnx", str(tmp_path / name), "--size", "48x32"]
        assert main(args) == 0
        exported.append((tmp_path / name).read_bytes())
    assert exported[0] == exported[1]
    repository = str(Path(__file__).parents[2]).encode()
    assert b" at 0x" not in exported[0] and repository not in exported[0]


def test_onnx_export_prints_lenspair_lines_only(
    tmp_path: Path, capfd: pytest.CaptureFixture[str], caplog: pytest.LogCaptureFixture
) -> None:
    # The exporter narrated each export: "[torch.onnx] ..." progress lines on
    # stdout and about 130 INFO lines of the onnxscript/onnx_ir optimiser passes,
    # more than half of what the demo printed.
    pytest.importorskip("onnxscript")
    checkpoint = make_checkpoint(tmp_path / "c.pt")
    caplog.set_level(logging.INFO)  # the CLI's level without --verbose
    chatter = logging.getLogger("onnx_ir")
    before = chatter.level
    assert (
        main(["export", str(checkpoint), "--onnx", str(tmp_path / "m.onnx"), "--size", "48x32"])
        == 0
    )
    assert chatter.level == before  # levels are restored after the export
    printed = capfd.readouterr()
    assert "[torch.onnx]" not in printed.out + printed.err
    assert "torchvision is not installed" not in printed.out + printed.err
    foreign = [r.name for r in caplog.records if not r.name.startswith("lenspair")]
    assert foreign == []
    # its own line stays, printed once (it was also logged, so it showed twice)
    assert printed.out.count("onnx: ") == 1
    assert not any("onnx: " in r.getMessage() for r in caplog.records if r.levelno >= logging.INFO)
    # what it is doing is said before the long silent part (tens of seconds on a CPU)
    stages = [r.getMessage() for r in caplog.records if r.getMessage().startswith("exporting ")]
    assert stages == [f"exporting {tmp_path / 'm.onnx'}, then checking and timing it at 48x32 "
                      "and 25x17"]  # fmt: skip


def test_torchscript_export_reloads_and_matches(tmp_path: Path) -> None:
    loaded = load_model(make_checkpoint(tmp_path / "c.pt"))
    check = export_torchscript(loaded.network, 1, tmp_path / "m.pt", (33, 47), runs=2)
    assert check.max_abs_diff is not None and check.max_abs_diff < 1e-5
    assert check.sizes_checked == ("47x33", "23x17")  # and at a second odd size
    script = torch.jit.load(str(tmp_path / "m.pt"))
    image = check_image(1, (33, 47))
    with torch.no_grad():
        assert script(image).shape == (1, 1, 33, 47)
        other = check_image(1, (65, 97))  # any size: the trace records the padding's arithmetic
        difference = (script(other) - loaded.network(other)[1]).abs().max()
        assert float(difference) < 1e-5


def test_an_onnx_export_runs_any_size_whole_and_agrees_with_the_checkpoint(
    tmp_path: Path,
) -> None:
    """H and W were fixed at --size: restore ran other sizes in tiles of it (up to 109 codes off).

    Sizes that are not multiples of the network's stride (4) go through its own
    padding and cropping, in the graph.
    """
    onnx = pytest.importorskip("onnx")
    pytest.importorskip("onnxruntime")
    from lenspair.model.evaluation.export import export_onnx

    network = load_model(make_checkpoint(tmp_path / "c.pt")).network
    check = export_onnx(network, 1, tmp_path / "m.onnx", (32, 48), runs=1)
    backend = OnnxBackend(tmp_path / "m.onnx", torch.device("cpu"))
    generator = torch.Generator().manual_seed(7)
    for height, width in ((64, 96), (65, 97), (97, 65), (33, 47), (9, 11), (8, 8)):
        image = torch.rand(2, 1, height, width, generator=generator)
        with torch.no_grad():
            expected = network(image)[1].numpy()
        restored = backend(image.numpy())  # as restore runs it: whole
        assert restored.shape == (2, 1, height, width)
        assert np.abs(restored - expected).max() < 1e-4, (height, width)
    assert backend.fixed_size is None and backend.forced_tiles is None
    declared = onnx.load(str(tmp_path / "m.onnx")).graph.input[0].type.tensor_type.shape.dim
    assert [d.dim_param or d.dim_value for d in declared] == ["batch", 1, "height", "width"]
    # export's own check ran at --size and at a second, odd size
    assert check.sizes_checked == ("48x32", "25x17") and check.size == "48x32"
    assert check.max_abs_diff is not None and check.max_abs_diff < 1e-4


def test_an_export_removes_what_a_killed_one_left_beside_its_file(tmp_path: Path) -> None:
    checkpoint = make_checkpoint(tmp_path / "c.pt")
    killed = tmp_path / f".m.pt.{dead_pid()}.x1x1x1x1.pt.tmp"
    running = tmp_path / f".m.pt.{os.getpid()}.x2x2x2x2.pt.tmp"  # a live writer's: kept
    other = tmp_path / f".n.pt.{dead_pid()}.x3x3x3x3.pt.tmp"  # another output's: kept
    for path in (killed, running, other):
        path.write_bytes(b"")
    argv = ["export", str(checkpoint), "--torchscript", str(tmp_path / "m.pt"), "--size", "32x48"]
    assert main(argv) == 0
    assert not killed.exists() and running.exists() and other.exists()


def test_export_without_onnxruntime_says_so(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    pytest.importorskip("onnx")
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec",
        lambda name, *a: None if name == "onnxruntime" else real(name, *a),
    )  # fmt: skip
    checkpoint = make_checkpoint(tmp_path / "c.pt")
    assert (
        main(["export", str(checkpoint), "--onnx", str(tmp_path / "m.onnx"), "--size", "48x32"])
        == 0
    )
    report = json.loads((tmp_path / "m.onnx.export.json").read_text())
    assert report["exports"][0]["max_abs_diff"] is None
    assert "onnxruntime is missing" in report["exports"][0]["note"]


def test_missing_targets(tmp_path: Path) -> None:
    assert main(["export", str(tmp_path / "c.pt")]) == 2


def test_failing_dynamo_exporter_falls_back_to_the_legacy_one(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    pytest.importorskip("onnx")
    import importlib.util

    from lenspair.model.evaluation import export

    real = importlib.util.find_spec
    monkeypatch.setattr(  # pretend onnxscript is installed; the dynamo exporter then fails
        importlib.util, "find_spec",
        lambda name, *a: real("json") if name == "onnxscript" else real(name, *a),
    )  # fmt: skip
    original = export.write_onnx

    def broken_dynamo(model: torch.nn.Module, image: torch.Tensor, path: Path, *,
                      exporter: str) -> None:  # fmt: skip
        if exporter == "dynamo":
            raise RuntimeError("dynamo exporter unavailable")
        original(model, image, path, exporter=exporter)

    monkeypatch.setattr(export, "write_onnx", broken_dynamo)
    network = load_model(make_checkpoint(tmp_path / "c.pt")).network
    check = export.export_onnx(network, 1, tmp_path / "m.onnx", (32, 48), runs=1)
    assert check.exporter == "torch.onnx (TorchScript-based)"
    assert check.max_abs_diff is not None and check.max_abs_diff < 1e-4
    # restore takes its file, of any size (it refused an output of unnamed channels)
    backend = OnnxBackend(tmp_path / "m.onnx", torch.device("cpu"))
    assert backend.channels == 1 and backend.fixed_size is None
    image = torch.rand(1, 1, 33, 47, generator=torch.Generator().manual_seed(2))
    with torch.no_grad():
        expected = network(image)[1].numpy()
    assert np.abs(backend(image.numpy()) - expected).max() < 1e-4


def _quantised_ops(graph: Any) -> set[str]:
    """Operators of a QDQ graph whose inputs are all dequantised and whose output is quantised."""
    constants = {t.name for t in graph.initializer}
    dequantised = {o for n in graph.node if n.op_type == "DequantizeLinear" for o in n.output}
    readers: dict[str, list[str]] = {}
    for node in graph.node:
        for name in node.input:
            readers.setdefault(name, []).append(node.op_type)
    found = set()
    for node in graph.node:
        inputs = [i for i in node.input if i and i not in constants]
        outputs = [readers.get(o, []) for o in node.output]
        if (
            node.op_type not in ("QuantizeLinear", "DequantizeLinear")
            and inputs
            and all(i in dequantised for i in inputs)
            and all(kinds and set(kinds) == {"QuantizeLinear"} for kinds in outputs)
        ):
            found.add(node.op_type)
    return found


def test_an_export_stopped_midway_leaves_no_earlier_export_beside_its_files(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Stopped in the int8 calibration, an export left its new model.onnx beside the last
    export's model.int8.onnx and report, which named the other checkpoint."""
    pytest.importorskip("onnxruntime")
    from lenspair.commands import export  # the module whose _export_int8 is stopped

    checkpoint = make_checkpoint(tmp_path / "c.pt")
    data = write_paired_folder(tmp_path / "pairs", count=2)
    earlier = {
        tmp_path / "model.int8.onnx": "another network",
        tmp_path / "model.onnx.export.json": "{}",
    }
    for path, text in earlier.items():
        path.write_text(text)

    def stopped(*args: object) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(export, "_export_int8", stopped)
    args = ["export", str(checkpoint), "--onnx", str(tmp_path / "model.onnx"), "--size", "48x32"]
    assert main([*args, "--int8", "--calibration", str(data)]) == 130
    assert (tmp_path / "model.onnx").is_file() and not any(p.exists() for p in earlier)
    assert "files without model.onnx.export.json are unfinished" in capsys.readouterr().err


def test_an_export_of_a_checkpoint_that_cannot_be_read_changes_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # the last export's int8 model and report went before the checkpoint was read, and
    # the ONNX file left beside no report read as an unfinished export
    earlier = {
        tmp_path / "model.onnx": "the last export",
        tmp_path / "model.int8.onnx": "its int8 twin",
        tmp_path / "model.onnx.export.json": "{}",
    }
    for path, text in earlier.items():
        path.write_text(text)
    (tmp_path / "bad.pt").write_text("junk")
    assert main(["export", str(tmp_path / "bad.pt"), "--onnx", str(tmp_path / "model.onnx")]) == 2
    assert {path: path.read_text() for path in earlier} == earlier
    assert "removed" not in capsys.readouterr().err


def test_int8_export_is_close_to_fp32_and_reloads(tmp_path: Path) -> None:
    ort = pytest.importorskip("onnxruntime")
    onnx = pytest.importorskip("onnx")
    checkpoint = make_checkpoint(tmp_path / "c.pt")
    data = write_paired_folder(tmp_path / "pairs", count=4)
    onnx_file = tmp_path / "model.onnx"
    args = ["export", str(checkpoint), "--onnx", str(onnx_file), "--size", "48x32"]
    assert main([*args, "--int8", "--calibration", str(data)]) == 0
    report = json.loads((tmp_path / "model.onnx.export.json").read_text())
    int8 = report["int8"]
    # 4 pairs: the model written is calibrated on all 4 (the comparison with fp32 is on
    # the one with the most contrast, held out of a probe model's calibration)
    assert int8["calibration_images"] == 4 and int8["precision"]["precision"] == "int8"
    assert int8["compared_on"] == "a held-out image"
    # what the ranges were fitted to: the data and the size (they fit frames of that size)
    assert int8["calibration"] == {"data": str(data), "images": 4, "size": [48, 32]}
    assert 25.0 < int8["psnr_vs_fp32_db"] < 100.0  # quantised: close, yet not identical
    session = ort.InferenceSession(int8["path"], providers=["CPUExecutionProvider"])
    # the contract travels with the files (a C++ node reads it without lenspair): they
    # carried none of it
    fp32_session = ort.InferenceSession(str(onnx_file), providers=["CPUExecutionProvider"])
    for each, precision in ((fp32_session, "fp32"), (session, "int8")):
        meta = each.get_modelmeta()
        said = meta.custom_metadata_map
        assert {k: said[k] for k in ("channels", "layout", "input_range", "precision")} == {
            "channels": "1", "layout": "NCHW", "input_range": "0..1", "precision": precision,
        }  # fmt: skip
        assert said["min_side"] == "8" and said["lenspair_version"]
        assert "float32 (N, 1, H, W), values in [0, 1]" in meta.description
    graph = onnx.load(int8["path"]).graph
    kinds = {node.op_type for node in graph.node}
    assert "QuantizeLinear" in kinds and "DequantizeLinear" in kinds
    # Only convolutions are quantised: they alone run between dequantised inputs
    # and a quantised output (DQ -> op -> Q, fused into an integer op), apart
    # from an activation squeezed between one convolution's output pair and
    # the next one's input pair. Quantising everything also caught the norms,
    # pads, pools, concatenations and adds.
    assert _quantised_ops(graph) - {"Relu", "LeakyRelu"} == set(QUANTISED_OPS)
    for height, width in ((32, 48), (65, 97)):  # any size, as the fp32 file: it was 48x32 only
        image = torch.rand(2, 1, height, width, generator=torch.Generator().manual_seed(3))
        (restored,) = session.run(None, {"image": image.numpy()})
        with torch.no_grad():
            expected = load_model(checkpoint).network(image)[1].numpy()
        assert restored.shape == (2, 1, height, width)
        assert np.abs(restored - expected).mean() < 0.05
    # restore's report names what ran: it said fp32 for the int8 model
    cpu = torch.device("cpu")
    assert OnnxBackend(Path(int8["path"]), cpu).description.endswith("(int8)")
    assert OnnxBackend(onnx_file, cpu).description.endswith("(fp32)")
    # each runs at its own precision: asking the int8 model for fp32 ran int8, unsaid
    assert open_backend(Path(int8["path"]), cpu, "int8").precision == "int8"
    assert open_backend(onnx_file, cpu, "auto").precision == "fp32"
    for path, asked in ((Path(int8["path"]), "fp32"), (onnx_file, "int8"), (onnx_file, "bf16")):
        with pytest.raises(ModelError, match=rf"--precision {asked}: .* ONNX model and runs as"):
            open_backend(path, cpu, asked)
    # the sessions do not spin between runs (they are timed beside torch)
    assert (
        open_session(onnx_file)
        .get_session_options()
        .get_session_config_entry("session.intra_op.allow_spinning")
        == "0"
    )
    # an export without --int8 over the same name took the ONNX file, not its int8 twin:
    # the two read as one network's pair
    assert main(args) == 0
    assert onnx_file.is_file() and not Path(int8["path"]).exists()


def test_int8_export_needs_calibration(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    checkpoint = make_checkpoint(tmp_path / "c.pt")
    assert main(["export", str(checkpoint), "--onnx", str(tmp_path / "m.onnx"), "--int8"]) == 2
    assert "--int8 needs --onnx FILE and --calibration DS" in capsys.readouterr().err


@pytest.mark.parametrize(
    "problem",
    [
        "missing folder",
        "missing split",
        "without --int8",
        "split alone",
        "split of a folder",
        "unreadable images",
    ],
)
def test_a_bad_calibration_is_refused_before_anything_is_written(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], problem: str
) -> None:
    checkpoint = make_checkpoint(tmp_path / "c.pt")
    onnx_file = tmp_path / "m.onnx"
    onnx_file.write_bytes(b"an earlier export")
    dataset = write_paired_folder(tmp_path / "pairs", count=2)
    args = ["export", str(checkpoint), "--onnx", str(onnx_file), "--size", "48x32"]
    if problem == "missing folder":
        args += ["--int8", "--calibration", str(tmp_path / "nope")]
    elif problem == "missing split":
        args += ["--int8", "--calibration", str(tmp_path), "--split", "nosuch"]
    elif problem == "without --int8":
        args += ["--calibration", str(dataset)]  # it was ignored without a word
    elif problem == "split alone":  # so was this
        args += ["--split", "val"]
    elif problem == "split of a folder":  # and this: a paired folder has no splits
        args += ["--int8", "--calibration", str(dataset), "--split", "val"]
    else:  # decoded only after the earlier export's files had gone and the new ONNX was in
        for image in (dataset / "input").iterdir():
            image.write_bytes(image.read_bytes()[:40])
        args += ["--int8", "--calibration", str(dataset)]
    assert main(args) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert {
        "missing folder": "nope",
        "missing split": "nosuch",
        "without --int8": "--int8 only",
        "split alone": "--split is the split of --calibration DS",
        "split of a folder": "is a paired folder, not a dataset with splits",
        "unreadable images": "int8 calibration: no image can be read",
    }[problem] in line
    # the fp32 export used to be written (overwriting this file) before the refusal
    assert onnx_file.read_bytes() == b"an earlier export"
    assert not (tmp_path / "m.onnx.export.json").exists()


def test_int8_check_compares_on_an_image_held_out_of_the_calibration(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    pytest.importorskip("onnxruntime")
    from lenspair.model.evaluation import quantize

    fitted: list[list[np.ndarray]] = []
    real = quantize.quantize_network

    def record(network: Any, channels: int, path: Path, size: Any, images: Any, **kw: Any) -> Any:
        fitted.append(list(images))
        return real(network, channels, path, size, images, **kw)

    monkeypatch.setattr(quantize, "quantize_network", record)
    network = load_model(make_checkpoint(tmp_path / "c.pt")).network
    rng = np.random.default_rng(0)
    images = [rng.random((1, 1, 32, 48), dtype=np.float32) for _ in range(3)]
    images.append(np.full((1, 1, 32, 48), 0.8, np.float32))  # flat: it flattered int8 last
    images[1] = images[1] * 0.2  # the least contrast of the textured ones
    check = quantize.check_int8(network, 1, tmp_path / "m.int8.onnx", (32, 48), images, runs=1)
    contrast = max(range(4), key=lambda i: float(images[i].std()))
    # compared on the one with the most contrast, held out of the probe's calibration
    assert len(fitted) == 2 and len(fitted[0]) == 3
    assert not any(image is images[contrast] for image in fitted[0])
    assert any(image is images[3] for image in fitted[0])
    # the model written is calibrated on every image, that one too (it was left out)
    assert check.calibration_images == 4 and len(fitted[1]) == 4
    assert check.compared_on == "a held-out image" and "on a held-out image" in check.summary()
    # one image leaves none to hold out: the check runs on noise, and says so (it did not)
    alone = quantize.check_int8(network, 1, tmp_path / "one.int8.onnx", (32, 48), images[:1], 1)
    assert alone.compared_on == "random noise" and "dB on random noise" in alone.summary()


def test_an_output_on_the_checkpoint_or_on_another_output_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    checkpoint = make_checkpoint(tmp_path / "c.pt")
    before = checkpoint.read_bytes()
    same, report = tmp_path / "m.onnx", tmp_path / "m.onnx.export.json"
    cases = {
        "the same file as the checkpoint": ["--torchscript", str(checkpoint)],
        # one file as both could only be an .onnx one, which --torchscript refuses
        "would take it for an ONNX model": ["--onnx", str(same), "--torchscript", str(same)],
        "the report " + str(report) + ": the same file as --torchscript": [
            "--onnx", str(tmp_path / "m.onnx"), "--torchscript", str(report),
        ],
    }  # fmt: skip
    for message, argv in cases.items():
        assert main(["export", str(checkpoint), "--size", "16x16", *argv]) == 2
        assert message in capsys.readouterr().err
    assert checkpoint.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.pt"]  # nothing written


def test_a_size_too_large_for_memory_is_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    from lenspair.model.evaluation import export

    def out_of_memory(*args: Any) -> Any:
        raise RuntimeError("[enforce fail] DefaultCPUAllocator: can't allocate memory: 4e10 bytes")

    monkeypatch.setattr(export, "export_torchscript", out_of_memory)
    checkpoint = make_checkpoint(tmp_path / "c.pt")
    argv = ["export", str(checkpoint), "--torchscript", str(tmp_path / "m.pt")]
    assert main([*argv, "--size", "100000x100000"]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert "--size 100000x100000: not enough memory" in line


def test_the_papers_gea_exports_with_a_dynamic_batch_that_restore_uses(tmp_path: Path) -> None:
    """Traced on batch 1, the GEA exported its batch fixed to 1 at 64x48 and larger, 540x360 too."""
    onnx = pytest.importorskip("onnx")
    pytest.importorskip("onnxruntime")
    from dataclasses import replace

    from lenspair.core.imagewrite import write_image
    from lenspair.model.inference.backends import open_backend
    from lenspair.model.inference.pipeline import restore_input
    from lenspair.model.inference.restore_options import RestoreOptions
    from lenspair.model.training.config import ModelConfig
    from tests.model.train_fixtures import clean_image, tiny_config

    config = replace(tiny_config(), model=ModelConfig(variant="GEA", channels=1))  # the paper's
    checkpoint = make_checkpoint(tmp_path / "gea.pt", config)
    model = tmp_path / "gea.onnx"
    assert main(["export", str(checkpoint), "--onnx", str(model), "--size", "64x48"]) == 0
    dims = onnx.load(str(model)).graph.input[0].type.tensor_type.shape.dim
    assert dims[0].dim_param and not dims[0].dim_value  # symbolic, not 1
    assert dims[2].dim_param and dims[3].dim_param  # so are H and W
    rng = np.random.default_rng(0)
    for index in range(3):
        write_image(tmp_path / "in" / f"{index}.png", clean_image(rng, 48, 64))
    write_image(tmp_path / "in" / "big.png", clean_image(rng, 90, 120))  # whole, not in tiles
    backend = open_backend(model, torch.device("cpu"))
    report = restore_input(tmp_path / "in", tmp_path / "out", backend, RestoreOptions(batch_size=2))
    assert (report.restored, report.failed, report.forced_tile) == (4, 0, None)


def test_a_flat_frame_stays_flat_through_onnx_runtime(tmp_path: Path) -> None:
    pytest.importorskip("onnx")
    ort = pytest.importorskip("onnxruntime")
    shipped = pretrained_weights(1)  # trained: an untrained GEA's zero heads hide its norms
    onnx_file = tmp_path / "gea.onnx"
    assert main(["export", str(shipped), "--onnx", str(onnx_file), "--size", "128x96"]) == 0
    report = json.loads((tmp_path / "gea.onnx.export.json").read_text())
    assert report["exports"][0]["max_abs_diff"] < 1e-4  # the check includes a flat frame
    session = ort.InferenceSession(str(onnx_file), providers=["CPUExecutionProvider"])
    frames = np.stack([np.full((1, 96, 128), v, np.float32) for v in (0.0, 0.5, 1.0)])
    (restored,) = session.run(None, {"image": frames})
    with torch.inference_mode():
        reference = load_model(shipped).network.restore(torch.from_numpy(frames)).numpy()
    # ONNX Runtime's rounding, amplified by the norms, made a grey frame 48..157 of 255
    assert float(np.abs(restored - reference).max()) < 1e-4
    inner = restored[..., 4:-4, 4:-4]
    assert float((inner.max(axis=(1, 2, 3)) - inner.min(axis=(1, 2, 3))).max()) < 2e-3


@pytest.mark.parametrize("option", ["--torchscript", "--onnx"])
def test_a_full_disk_is_one_line_naming_the_file_and_leaves_no_temporary(
    tmp_path: Path, option: str
) -> None:
    from tests.file_limits import run_with_file_limit

    checkpoint = make_checkpoint(tmp_path / "c.pt")
    out = tmp_path / "out" / ("m.pt" if option == "--torchscript" else "m.onnx")
    out.parent.mkdir()
    argv = ["export", str(checkpoint), option, str(out), "--size", "48x32"]
    failed = run_with_file_limit(argv, limit=checkpoint.stat().st_size // 4)
    # torch.jit.save aborted from C++ (exit 134, a stack dump); ONNX tried its
    # second exporter, then said "ONNX export failed" with exit 2
    assert failed.returncode == 1, failed.stderr
    lines = failed.stderr.strip().splitlines()
    assert lines[-1] == f"lenspair export: error: {out}: File too large", failed.stderr
    assert "Traceback" not in failed.stderr and "terminate called" not in failed.stderr
    assert list(out.parent.iterdir()) == []


@pytest.mark.parametrize("code", REFUSALS)
def test_a_folder_that_refuses_the_onnx_file_is_one_line_and_no_second_exporter(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    caplog: pytest.LogCaptureFixture,
    code: int,
) -> None:
    """Read-only or another user's folder: exit 1 naming the file, as every command says it."""
    pytest.importorskip("onnxscript")
    checkpoint = make_checkpoint(tmp_path / "c.pt")
    out = tmp_path / "ro" / "m.onnx"
    out.parent.mkdir()
    refuse_writes(monkeypatch, out.parent, code)
    assert main(["export", str(checkpoint), "--onnx", str(out), "--size", "48x32"]) == 1
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line == f"lenspair export: error: {out}: {os.strerror(code)}"
    assert not any("trying legacy" in r.getMessage() for r in caplog.records)


def test_an_output_that_is_a_training_checkpoint_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``.pt`` is a run's suffix too: exporting onto last.pt cost the run its resume."""
    checkpoint = make_checkpoint(tmp_path / "run" / "best.pt")
    last = make_checkpoint(tmp_path / "run" / "last.pt")
    before = last.read_bytes()
    argv = ["export", str(checkpoint), "--torchscript", str(last), "--size", "48x32"]
    assert main(argv) == 2
    assert "a lenspair checkpoint or detector, which the export would overwrite" in (
        capsys.readouterr().err
    )
    assert last.read_bytes() == before
    # a detector too: train-detector's detector.pt was overwritten without a word
    detector = tmp_path / "run" / "detector.pt"
    save_detector(detector, AnomalyDetector(DetectorSpec()))
    kept = detector.read_bytes()
    assert main([*argv[:3], str(detector), *argv[4:]]) == 2
    assert "a lenspair checkpoint or detector" in capsys.readouterr().err
    assert detector.read_bytes() == kept
    other = tmp_path / "run" / "model.pt"  # an earlier export there is replaced, as before
    assert (
        main([*argv[:3], str(other), *argv[4:]]) == 0
        and main([*argv[:3], str(other), *argv[4:]]) == 0
    )


def test_an_export_to_files_another_export_is_writing_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # two exports to one --onnx left one's network under the other's report (a G network
    # beside a report naming the GEA checkpoint and claiming its check)
    from lenspair.core.folderlock import lock_file

    checkpoint = make_checkpoint(tmp_path / "c.pt")
    onnx = tmp_path / "m.onnx"
    held = lock_file(tmp_path / ".m.onnx.export.json.lock", "export")  # the other export
    assert held is not None
    try:
        capsys.readouterr()
        args = ["export", str(checkpoint), "--onnx", str(onnx), "--size", "48x32"]
        assert main(args) == 2
    finally:
        os.close(held)
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].endswith(
        f"{onnx}: another export is writing it; wait for it to finish or write another file"
    )
    assert not onnx.exists() and not (tmp_path / "m.onnx.export.json").exists()

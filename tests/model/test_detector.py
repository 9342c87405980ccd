"""The detector network, its training step and its checkpoints."""

from pathlib import Path

import numpy as np
import pytest
import torch

from lenspair.model.detection.data import UNKNOWN_KIND, synthetic_samples, texture_images
from lenspair.model.detection.judge import judge
from lenspair.model.detection.train import (
    SKIPPED_KIND,
    DetectorTraining,
    crop_batch,
    detector_loss,
    load_detector,
    save_detector,
    train_detector,
)
from lenspair.model.errors import ModelError
from lenspair.model.networks.detector import (
    KINDS,
    AnomalyDetector,
    DetectorSpec,
    count_parameters,
)

SMALL = DetectorSpec(widths=(4, 8, 8), context_dilations=(2,), input_size=(48, 64))


def test_default_detector_is_small_and_maps_at_one_sixteenth_of_a_frame() -> None:
    network = AnomalyDetector()
    assert count_parameters(network) < 300_000
    # 540x360 frames are judged at 270x180; the map is 1/16 of the frame.
    assert network.spec.grid == (-(-360 // 16), -(-540 // 16))


@pytest.mark.parametrize("size", [(48, 64), (37, 53)])
def test_output_shapes_and_obstructed_is_one_minus_clean(one_thread: None, size: tuple) -> None:
    torch.manual_seed(0)
    network = AnomalyDetector(SMALL).eval()
    with torch.no_grad():
        output = network(torch.rand(3, 1, *size))
    assert output.kind_logits.shape == (3, len(KINDS))
    assert output.tile_logits.shape == (3, -(-size[0] // 8), -(-size[1] // 8))
    clean = torch.softmax(output.kind_logits, dim=1)[:, 0]
    torch.testing.assert_close(output.obstructed, 1.0 - clean)


def test_rejects_colour_input() -> None:
    with pytest.raises(ValueError, match=r"expected \(N, 1, H, W\)"):
        AnomalyDetector(SMALL)(torch.rand(1, 3, 48, 64))


def test_training_lowers_the_loss(one_thread: None) -> None:
    samples = synthetic_samples(
        texture_images(["brick", "grass"]), 16, SMALL, np.random.default_rng(0)
    )
    settings = DetectorTraining(steps=80, batch_size=8, learning_rate=1e-2, seed=1)
    _, summary = train_detector(samples, SMALL, settings)
    assert summary.steps == 80
    assert summary.last_loss < 0.8 * summary.first_loss


def test_without_a_step_limit_training_runs_until_the_time_limit(one_thread: None) -> None:
    # "--minutes 5" trained 600 steps in 15 s: the default step count ended it first
    samples = synthetic_samples(texture_images(["brick"]), 4, SMALL, np.random.default_rng(0))
    settings = DetectorTraining(steps=None, batch_size=2, seed=1, max_seconds=0.5)
    _, summary = train_detector(samples, SMALL, settings)
    assert summary.seconds >= 0.5 and summary.steps > 1
    with pytest.raises(ModelError, match="no step limit"):
        DetectorTraining(steps=None)


def test_training_rejects_samples_of_another_size() -> None:
    samples = synthetic_samples(texture_images(["brick"]), 2, SMALL, np.random.default_rng(0))
    with pytest.raises(ModelError, match="expected"):
        train_detector(samples, DetectorSpec(), DetectorTraining(steps=1))


def test_checkpoint_round_trip(tmp_path: Path, one_thread: None) -> None:
    torch.manual_seed(3)
    network = AnomalyDetector(SMALL).eval()
    save_detector(tmp_path / "d.pt", network)
    loaded = load_detector(tmp_path / "d.pt")
    assert loaded.spec == SMALL
    # a device as Restorer and the command line take it: "auto" was torch's RuntimeError
    assert next(load_detector(tmp_path / "d.pt", "auto").parameters()).device.type in (
        "cpu",
        "cuda",
    )
    image = (np.random.default_rng(0).random((60, 80)) * 255).astype(np.uint8)
    first, second = judge(network, [image]), judge(loaded, [image])
    np.testing.assert_array_equal(first.probability, second.probability)
    np.testing.assert_array_equal(first.maps, second.maps)


def test_a_saved_detector_is_the_same_bytes_wherever_it_is_saved(tmp_path: Path) -> None:
    # saved by torch to the file, its entries were named after the temporary beside it
    torch.manual_seed(3)
    network = AnomalyDetector(SMALL)
    save_detector(tmp_path / "a.pt", network)
    save_detector(tmp_path / "sub" / "b.pt", network)
    assert (tmp_path / "a.pt").read_bytes() == (tmp_path / "sub" / "b.pt").read_bytes()


def _damaged(data: dict, how: str) -> None:
    """Damage a detector checkpoint's contents in place, as a foreign or broken writer would."""
    if how == "no kinds":
        del data["kinds"]
    elif how == "unknown spec field":
        data["spec"]["bogus"] = [1]
    elif how == "spec too small":
        data["spec"]["input_size"] = [4, 4]
    elif how == "spec too large":
        data["spec"]["input_size"] = [100000, 100000]  # OpenCV's out-of-memory traceback
    elif how == "zero dilation":
        data["spec"]["context_dilations"] = [0, 4, 8]  # torch's traceback, after registration
    elif how == "fractional size":
        data["spec"]["input_size"] = [180.5, 270.0]  # was cut to 180 without a word
    elif how == "weights of another spec":
        data["spec"]["widths"] = [8, 8, 8]
    elif how == "NaN weights":
        for value in data["state_dict"].values():
            if value.is_floating_point():
                value.fill_(float("nan"))


@pytest.mark.parametrize(
    ("how", "said"),
    [
        ("no kinds", r"not a usable detector checkpoint \(no 'kinds' in it\)"),
        ("unknown spec field", r"not a usable detector checkpoint \(.*'bogus'"),
        ("spec too small", r"not a usable detector checkpoint \(input_size: expected at least"),
        ("spec too large", r"not a usable detector checkpoint \(input_size: expected sides up"),
        ("zero dilation", r"not a usable detector checkpoint \(context_dilations: expected pos"),
        ("fractional size", r"not a usable detector checkpoint \(.*float"),
        ("weights of another spec", r"weights do not fit its spec: .*size mismatch"),
        ("NaN weights", r"its weights hold NaN or Inf"),  # judged every frame NaN, exit 0
    ],
)
def test_a_damaged_detector_checkpoint_is_one_line_naming_it(
    tmp_path: Path, how: str, said: str
) -> None:
    save_detector(tmp_path / "d.pt", AnomalyDetector(SMALL))
    data = torch.load(tmp_path / "d.pt", weights_only=True)
    _damaged(data, how)
    torch.save(data, tmp_path / "d.pt")
    with pytest.raises(ModelError, match=rf"^{tmp_path / 'd.pt'}: .*{said}") as caught:
        load_detector(tmp_path / "d.pt")
    assert "\n" not in str(caught.value)


def test_a_run_folder_given_as_the_detector_points_to_its_detector(tmp_path: Path) -> None:
    save_detector(tmp_path / "run" / "detector.pt", AnomalyDetector(SMALL))
    with pytest.raises(ModelError, match=r"a folder, not a detector .* is \S*run/detector\.pt$"):
        load_detector(tmp_path / "run")


def test_loading_something_else_is_a_one_line_error(tmp_path: Path) -> None:
    torch.save({"state_dict": {}}, tmp_path / "other.pt")
    with pytest.raises(ModelError, match="not a detector checkpoint"):
        load_detector(tmp_path / "other.pt")
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(ModelError, match=r"junk\.pt"):
        load_detector(tmp_path / "junk.pt")
    with pytest.raises(ModelError, match="no such"):
        load_detector(tmp_path / "missing.pt")


def test_judge_takes_any_size_grey_or_colour_8_or_16_bit(one_thread: None) -> None:
    network = AnomalyDetector(SMALL).eval()
    rng = np.random.default_rng(1)
    images = [
        (rng.random((90, 120)) * 255).astype(np.uint8),
        (rng.random((50, 70, 3)) * 65535).astype(np.uint16),
    ]
    verdict = judge(network, images, batch_size=1)
    assert verdict.probability.shape == (2,)
    assert verdict.maps.shape == (2, *SMALL.grid)
    np.testing.assert_allclose(verdict.kind_probabilities.sum(axis=1), 1.0, rtol=1e-5)
    assert len(verdict.kinds) == 2 and set(verdict.kinds) <= set(KINDS)


def test_blank_frames_are_never_called_obstructed(one_thread: None) -> None:
    network = AnomalyDetector(SMALL).eval()
    with torch.no_grad():  # force the network to say "rain" for everything
        network.kind_head.bias.copy_(torch.tensor([-50.0, 50.0, 0.0, 0.0]))
    black = np.zeros((60, 80), np.uint8)
    saturated = np.full((60, 80, 3), 65535, np.uint16)
    textured = (np.random.default_rng(2).random((60, 80)) * 255).astype(np.uint8)
    verdict = judge(network, [black, saturated, textured])
    assert verdict.blank.tolist() == [True, True, False]
    assert verdict.obstructed.tolist() == [False, False, True]
    assert verdict.kinds == ["clean", "clean", "rain"]
    assert np.isfinite(verdict.maps).all() and np.isfinite(verdict.probability).all()


def test_16_bit_frames_of_12_bit_values_are_judged_as_their_full_range_twin(
    tmp_path: Path, one_thread: None
) -> None:
    # mono16 words of a Mono12 camera were all but black: a blank frame, never obstructed
    from lenspair.capture.frame_types import InputFrame
    from lenspair.core.bitdepth import narrow
    from lenspair.model.detection.report import detect_frames

    torch.manual_seed(5)
    network = AnomalyDetector(SMALL).eval()
    # a dim scene: its 12-bit values vary by less than one 8-bit level of the 16-bit range
    dim = 0.02 + 0.03 * np.random.default_rng(2).random((60, 80))
    full = (dim * 65535).astype(np.uint16)

    def verdicts(image: np.ndarray, out: str) -> list:
        frames = [InputFrame(i, f"f{i}.png", None, None, "x", image, None) for i in range(2)]
        return detect_frames(network, frames, tmp_path / out, sheet_frames=0)

    twin, low = verdicts(full, "full"), verdicts(narrow(full, 12), "low")
    assert [v.blank for v in low] == [v.blank for v in twin] == [False, False]
    for ours, theirs in zip(low, twin, strict=True):
        assert abs(ours.probability - theirs.probability) < 5e-3  # 12 of 16 bits
    assert judge(network, [narrow(full, 12)], bits=16).blank.tolist() == [True]  # as read


def test_judge_widens_16_bit_frames_of_10_bit_values_as_detect_does(one_thread: None) -> None:
    # mono16 words of a Mono10 camera were judged as read: all blank, never obstructed
    from lenspair.core.bitdepth import narrow, widen

    torch.manual_seed(6)
    network = AnomalyDetector(SMALL).eval()
    rng = np.random.default_rng(3)
    # a textured scene, read as it is nearly black: its values vary by a third of an 8-bit level
    full = [((0.2 + 0.3 * rng.random((60, 80))) * 65535).astype(np.uint16) for _ in range(3)]
    low = [narrow(image, 10) for image in full]
    twin = judge(network, [widen(image, 10) for image in low])  # on the full scale already
    verdict = judge(network, low)
    assert verdict.blank.tolist() == twin.blank.tolist() == [False, False, False]
    np.testing.assert_allclose(verdict.probability, twin.probability, atol=1e-6)
    np.testing.assert_allclose(verdict.maps, twin.maps, atol=1e-6)
    # an 8-bit frame in the call: 16-bit ones are taken as they are, as significant_bits says
    mixed = judge(network, [low[0], (rng.random((60, 80)) * 255).astype(np.uint8)])
    assert mixed.blank.tolist() == [True, False]
    with pytest.raises(ValueError, match=r"judge takes a list of frames, got one \(60, 80\)"):
        judge(network, low[0])  # iterated, its 60 rows were judged as 60 frames
    with pytest.raises(ValueError, match=r"bits: expected one of 10, 12, 16, got 8"):
        judge(network, low, bits=8)
    # a generator had no len(); batch_size 0 was range()'s "arg 3 must not be zero"
    from_generator = judge(network, (image for image in low))
    np.testing.assert_array_equal(from_generator.probability, verdict.probability)
    with pytest.raises(ValueError, match=r"batch_size: expected a whole number of frames >= 1"):
        judge(network, low, batch_size=0)
    with pytest.raises(ValueError, match=r"^frame 1: 40x1 pixels, smaller than the 8x8 min"):
        judge(network, [low[0], low[0][:1, :40]])
    # a NumPy integer (an array's length, a value read with NumPy) is a whole number too
    by_numpy = judge(network, low, batch_size=np.int64(2))  # type: ignore[arg-type]
    np.testing.assert_array_equal(by_numpy.probability, verdict.probability)
    with pytest.raises(ValueError, match=r"batch_size: expected a whole number of frames >= 1"):
        judge(network, low, batch_size=True)
    # 12.0 == 12 passed the check and failed in the shift with a TypeError
    with pytest.raises(ValueError, match=r"bits: expected one of 10, 12, 16, got 12.0"):
        judge(network, low, bits=12.0)  # type: ignore[arg-type]


def test_judge_names_the_index_of_a_frame_it_cannot_take(one_thread: None) -> None:
    network = AnomalyDetector(SMALL).eval()
    good = np.zeros((60, 80), np.uint8)
    with pytest.raises(ValueError, match=r"^frame 2: expected dtype uint8 or uint16, got float32"):
        judge(network, [good, good, good.astype(np.float32)], batch_size=2)
    with pytest.raises(ValueError, match=r"^frame 1: expected shape \(H, W\) or \(H, W, 3\)"):
        judge(network, [good, np.zeros((60, 80, 4), np.uint8)])


def test_detect_names_its_input_when_the_bit_depth_rises(
    tmp_path: Path, one_thread: None, caplog: pytest.LogCaptureFixture
) -> None:
    # the warning said "the input", naming no file
    from lenspair.capture.frame_types import InputFrame
    from lenspair.model.detection.report import detect_frames

    network = AnomalyDetector(SMALL).eval()
    rng = np.random.default_rng(4)
    twelve = (rng.random((60, 80)) * 4095).astype(np.uint16)
    sixteen = (rng.random((60, 80)) * 65535).astype(np.uint16)
    frames = [
        InputFrame(i, f"f{i}.png", None, None, "x", image, None)
        for i, image in enumerate([twelve, sixteen])
    ]
    root = tmp_path / "rec_mono12"
    with caplog.at_level("WARNING", logger="lenspair.core.bitdepth"):
        detect_frames(network, frames, tmp_path / "out", sheet_frames=0, root=root)
    said = [r.getMessage() for r in caplog.records if r.name == "lenspair.core.bitdepth"]
    assert len(said) == 2, said  # 12-bit values, then a frame above them
    assert all(message.startswith(f"{root}: ") for message in said), said


def test_training_windows_cut_maps_exactly_and_drop_kinds_without_anomaly() -> None:
    images = torch.arange(4 * 48 * 64, dtype=torch.float32).reshape(4, 1, 48, 64)
    tiles = torch.zeros(4, 6, 8)
    tiles[0, 0, 0] = 1.0  # only in the top-left tile
    tiles[2] = 1.0  # covered everywhere, of no known kind
    batch = {
        "images": images,
        "kinds": torch.tensor([KINDS.index("dirt"), KINDS.index("rain"), UNKNOWN_KIND, 0]),
        "tiles": tiles,
        "valid": torch.ones(4, 6, 8, dtype=torch.bool),
    }
    for seed in range(6):
        cropped = crop_batch(batch, (2, 3), torch.Generator().manual_seed(seed))
        assert cropped["images"].shape == (4, 1, 16, 24)
        assert cropped["tiles"].shape == (4, 2, 3)
        # the window's first pixel is the first pixel of its first tile
        first = int(cropped["images"][0, 0, 0, 0])
        row, col = divmod(first, 64)
        assert row % 8 == 0 and col % 8 == 0
        assert float(cropped["tiles"][0].sum()) == float(tiles[0, row // 8, col // 8])
        has_dirt = bool(cropped["tiles"][0].sum() > 0)
        assert int(cropped["kinds"][0]) == (KINDS.index("dirt") if has_dirt else SKIPPED_KIND)
        assert int(cropped["kinds"][1]) == SKIPPED_KIND  # rain frame with no covered tile
        assert cropped["kinds"][2:].tolist() == [UNKNOWN_KIND, 0]


def _kind_logit_gradients(kinds: list[int]) -> tuple[torch.Tensor, torch.Tensor]:
    """A small detector's kind logits on random frames, and the kind loss's gradient on them."""
    torch.manual_seed(0)
    network = AnomalyDetector(SMALL).eval()
    seen: list[torch.Tensor] = []

    def keep(module: torch.nn.Module, inputs: object, output: torch.Tensor) -> None:
        output.retain_grad()
        seen.append(output)

    network.kind_head.register_forward_hook(keep)
    count = len(kinds)
    batch = {
        "images": torch.rand(
            count, 1, *SMALL.input_size, generator=torch.Generator().manual_seed(1)
        ),
        "kinds": torch.tensor(kinds),
        "tiles": torch.ones(count, *SMALL.grid),
        "valid": torch.ones(count, *SMALL.grid, dtype=torch.bool),
    }
    detector_loss(network, batch, map_weight=0.0).backward()
    (logits,) = seen
    assert logits.grad is not None
    return logits.detach(), logits.grad


def test_positives_of_unknown_kind_train_the_obstructed_answer(one_thread: None) -> None:
    """p(obstructed) is 1 - p(clean): a positive labelled fog must push p(clean) down."""
    logits, gradient = _kind_logit_gradients([UNKNOWN_KIND, 0])
    assert float(gradient[0, 0]) > 0.0  # a step down the gradient lowers its clean logit...
    assert bool((gradient[0, 1:] < 0.0).all())  # ...and raises every anomaly's
    before = torch.softmax(logits, dim=1)[:, 0]
    after = torch.softmax(logits - 0.5 * gradient, dim=1)[:, 0]
    assert float(after[0]) < float(before[0])  # the unknown positive: less clean
    assert float(after[1]) > float(before[1])  # the clean frame: more clean, as before
    # d/dz_clean of -log(1 - p(clean)) is p(clean); the loss averages over the two frames
    clean = torch.softmax(logits[0], dim=0)[0]
    assert float(gradient[0, 0]) == pytest.approx(0.5 * float(clean), rel=1e-4)


def test_a_skipped_training_window_takes_no_part_in_the_kind_loss(one_thread: None) -> None:
    _, gradient = _kind_logit_gradients([SKIPPED_KIND, UNKNOWN_KIND, 0])
    assert not gradient[0].any()  # its window showed no anomaly: neither kind nor obstructed
    assert gradient[1:].abs().sum(dim=1).gt(0).all()


@pytest.mark.parametrize(
    "device",
    [
        "cpu",
        pytest.param(
            "cuda",
            marks=pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device"),
        ),
    ],
)
def test_training_and_judging_on_a_device(tmp_path: Path, device: str, one_thread: None) -> None:
    samples = synthetic_samples(texture_images(["brick"]), 8, SMALL, np.random.default_rng(0))
    settings = DetectorTraining(steps=3, batch_size=4, seed=2)
    network, summary = train_detector(samples, SMALL, settings, device=device)
    assert summary.steps == 3 and np.isfinite(summary.last_loss)
    assert next(network.parameters()).device.type == device
    frames = [(np.random.default_rng(1).random((36, 54)) * 255).astype(np.uint8)]
    on_device = judge(network, frames)
    save_detector(tmp_path / "d.pt", network)
    back = judge(load_detector(tmp_path / "d.pt"), frames)  # loaded onto the CPU
    np.testing.assert_allclose(on_device.probability, back.probability, atol=1e-4)
    assert isinstance(on_device.probability, np.ndarray)


def test_the_bundled_detector_loads_by_its_name_as_the_docstring_says(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)  # no detector.pt here
    network = load_detector(Path("detector.pt"))
    assert isinstance(network, AnomalyDetector) and not network.training
    with pytest.raises(ModelError, match=r"^elsewhere/detector.pt: no such detector checkpoint"):
        load_detector(Path("elsewhere/detector.pt"))  # a path is a path


def test_an_exported_model_given_as_the_detector_is_one_line(
    tmp_path: Path, recwarn: pytest.WarningsRecorder
) -> None:
    # torch.load printed a UserWarning about TorchScript archives before the error
    scripted = torch.jit.script(torch.nn.Linear(2, 2))
    torch.jit.save(scripted, str(tmp_path / "ts.pt"))
    with pytest.raises(ModelError, match=r"ts\.pt: a TorchScript model .*not a detector"):
        load_detector(tmp_path / "ts.pt")
    assert not [w for w in recwarn if "TorchScript" in str(w.message)]


def test_restore_judges_its_frames_as_already_widened(monkeypatch: pytest.MonkeyPatch) -> None:
    # restore's batching widened the frame to the run's depth: judging it by its own
    # brightest pixel would brighten a dark 16-bit frame again (up to 64x)
    from lenspair.model.inference import judge as restore_judge  # the module, to patch

    seen: list[int | None] = []

    def spy(network: object, frames: object, bits: int | None = None) -> object:
        seen.append(bits)
        return judge(network, frames, bits=bits)  # type: ignore[arg-type]

    monkeypatch.setattr(restore_judge, "judge", spy)
    network = load_detector(Path("detector.pt"))
    dark = (np.random.default_rng(0).random((96, 128)) * 900).astype(np.uint16)
    assert judge(network, [dark]).blank[0] != judge(network, [dark], bits=16).blank[0]
    verdict = restore_judge.DetectorJudge(network)(None, dark)  # type: ignore[arg-type]
    assert seen == [16] and verdict is bool(judge(network, [dark], bits=16).obstructed[0])


def test_a_contact_sheet_cell_is_drawn_on_the_shrunk_frame(monkeypatch: pytest.MonkeyPatch) -> None:
    """The overlay was drawn at full size and shrunk after: ~35 bytes a pixel, so one huge
    frame in a folder got detect killed for memory before it wrote any verdict."""
    from lenspair.model.detection import report

    drawn: list[tuple[int, ...]] = []
    real = report.overlay
    monkeypatch.setattr(report, "overlay", lambda i, t: drawn.append(i.shape) or real(i, t))
    frame = np.zeros((2400, 3600), np.uint16)
    frame[:, :1800] = 60000  # the left half bright
    tiles = np.zeros((150, 225), np.float32)
    tiles[:, 200:] = 1.0  # the right edge obstructed
    cell = report.sheet_cell(frame, tiles)
    assert drawn == [(320, 480)] and cell.shape == (320, 480, 3)
    assert cell[:, :200].min() > 200  # bright, untinted
    assert tuple(cell[160, 470]) == (128, 0, 0)  # black, tinted half red

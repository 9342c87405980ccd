"""The precision decision, with the hardware probe mocked both ways."""

from pathlib import Path

import pytest
import torch

from lenspair.model.errors import ModelError
from lenspair.model.precision import (
    BF16_MIN_SPEED,
    Hardware,
    apply_isa_cap,
    choose_precision,
    measure_bf16_speed,
    native_precisions,
    onednn_isa_cap,
    probe_hardware,
    read_cpu_flags,
)
from lenspair.model.precision_measure import speed_ratio

CPU = torch.device("cpu")
CUDA = torch.device("cuda", 0)


def _cpu(*flags: str) -> Hardware:
    return Hardware("cpu", "Test CPU", frozenset({"sse2", "avx2", "avx512f", *flags}), "mock")


def _gpu(major: int, minor: int) -> Hardware:
    return Hardware("cuda", "Test GPU", cuda_capability=(major, minor))


def _probe(hardware: Hardware):  # type: ignore[no-untyped-def]
    return lambda device: hardware


def _speed(ratio: float, asked: list[str] | None = None):  # type: ignore[no-untyped-def]
    def measure(task: str) -> float:
        if asked is not None:
            asked.append(task)
        return ratio

    return measure


def test_native_bf16_cpu_trains_and_infers_in_bf16_where_it_measured_faster() -> None:
    hardware = _cpu("avx512_bf16", "avx512_vnni")
    asked: list[str] = []
    for task in ("train", "infer"):
        decision = choose_precision("auto", CPU, task, _probe(hardware), _speed(1.9, asked))  # type: ignore[arg-type]
        assert decision.precision == "bf16"
        assert "avx512_bf16" in decision.reason and "1.90x" in decision.reason
        assert decision.native == ("int8", "bf16", "fp32")
        assert not decision.emulated
        assert decision.autocast_dtype == torch.bfloat16
        assert decision.as_dict()["bf16_speed"] == 1.9
    assert asked == ["train", "infer"]  # each task measured as itself


@pytest.mark.parametrize("ratio", [0.57, 0.9, 1.05, BF16_MIN_SPEED - 0.01])  # 1.05: the margin
def test_native_bf16_that_measured_slower_than_fp32_is_not_chosen(ratio: float) -> None:
    # an Intel Xeon whose hypervisor hides AMX: avx512_bf16 is there, and 0.6x fp32
    hardware = _cpu("avx512_bf16", "avx512_vnni")
    decision = choose_precision("auto", CPU, "infer", _probe(hardware), _speed(ratio))
    assert decision.precision == "fp32" and decision.autocast_dtype is None
    assert decision.native == ("int8", "bf16", "fp32")  # still native: on request it runs
    assert f"measured {ratio:.2f}x fp32's speed" in decision.reason
    assert decision.bf16_speed == ratio
    forced = choose_precision("bf16", CPU, "train", _probe(hardware), _speed(ratio))
    assert forced.precision == "bf16" and not forced.emulated


def test_only_auto_on_a_bf16_cpu_measures() -> None:
    asked: list[str] = []
    choose_precision("auto", CPU, "train", _probe(_cpu("avx512_vnni")), _speed(2.0, asked))
    choose_precision("bf16", CPU, "train", _probe(_cpu("avx512_bf16")), _speed(2.0, asked))
    choose_precision("fp32", CPU, "infer", _probe(_cpu("avx512_bf16")), _speed(2.0, asked))
    choose_precision("auto", CUDA, "train", _probe(_gpu(9, 0)), _speed(2.0, asked))
    assert asked == []


def test_speed_ratio_is_the_median_of_alternating_pairs() -> None:
    now = [0.0]
    warmup, timed = [1.0, 1.0, 1.0, 1.0], [4.0, 1.0, 4.0, 2.0, 40.0, 1.0]
    costs = iter([*warmup, *timed])

    def run() -> None:
        now[0] += next(costs)

    # timed pairs: 4/1, 4/2, 40/1 -> median 4: one disturbed pair does not move it
    assert speed_ratio(run, run, repeats=3, warmup=2, clock=lambda: now[0]) == 4.0


def test_measured_bf16_speed_is_a_positive_ratio_kept_per_process() -> None:
    torch.manual_seed(7)
    expected = torch.rand(3)
    torch.manual_seed(7)
    first = measure_bf16_speed("train")
    # measuring leaves the global generator alone: a run draws the same numbers either way
    assert torch.equal(torch.rand(3), expected)
    assert 0.01 < first < 100.0  # emulated bf16 (AVX2 only) ran about 0.1x
    assert measure_bf16_speed("train") == first  # measured once per process


def test_amx_counts_as_native_bf16_and_int8() -> None:
    assert native_precisions(_cpu("amx_bf16", "amx_int8")) == ("int8", "bf16", "fp32")


def test_vnni_only_cpu_never_chooses_emulated_bf16() -> None:
    hardware = _cpu("avx512_vnni")
    decision = choose_precision("auto", CPU, "train", _probe(hardware))
    assert decision.precision == "fp32"
    assert decision.native == ("int8", "fp32")
    assert "not native" in decision.reason
    assert decision.autocast_dtype is None


def test_cpu_without_either_runs_fp32_and_marks_bf16_emulated() -> None:
    hardware = _cpu()
    assert choose_precision("auto", CPU, "infer", _probe(hardware)).precision == "fp32"
    forced = choose_precision("bf16", CPU, "train", _probe(hardware))
    assert forced.precision == "bf16" and forced.emulated
    assert "NOT native" in forced.reason


def test_unknown_flags_fall_back_to_fp32() -> None:
    hardware = Hardware("cpu", "somewhere", frozenset(), "no /proc/cpuinfo")
    decision = choose_precision("auto", CPU, "train", _probe(hardware))
    assert decision.precision == "fp32"
    assert "no /proc/cpuinfo" in decision.reason


@pytest.mark.parametrize(
    ("capability", "native"),
    [
        ((6, 1), ("fp32",)),
        ((7, 5), ("fp16", "fp32")),
        ((8, 6), ("bf16", "fp16", "fp32")),
        ((9, 0), ("bf16", "fp16", "fp32")),
    ],
)
def test_cuda_native_set_follows_compute_capability_and_auto_stays_fp32(
    capability: tuple[int, int], native: tuple[str, ...]
) -> None:
    decision = choose_precision("auto", CUDA, "train", _probe(_gpu(*capability)))
    assert decision.native == native
    # measured on an H100: fp32 beats bf16/fp16 autocast for these small networks
    assert decision.precision == "fp32"
    assert ("measured" in decision.reason) == (len(native) > 1)
    for precision in native:
        requested = choose_precision(precision, CUDA, "train", _probe(_gpu(*capability)))
        assert requested.precision == precision and not requested.emulated


def test_refused_combinations_name_the_option() -> None:
    with pytest.raises(ModelError, match="precision fp16 runs on CUDA only"):
        choose_precision("fp16", CPU, "infer", _probe(_cpu("avx512_bf16")))
    with pytest.raises(ModelError, match="precision int8 is for CPU inference"):
        choose_precision("int8", CPU, "train", _probe(_cpu("avx512_vnni")))
    with pytest.raises(ModelError, match="precision int8 is for CPU inference"):
        choose_precision("int8", CUDA, "train", _probe(_gpu(8, 0)))
    with pytest.raises(ModelError, match="expected one of auto, fp32"):
        choose_precision("fp8", CPU, "infer", _probe(_cpu()))


def test_each_int8_refusal_gives_its_caller_a_hint_it_can_follow() -> None:
    # training: no int8 anywhere, so name the precisions a run can train at
    for device, probe in ((CPU, _probe(_cpu("avx512_vnni"))), (CUDA, _probe(_gpu(9, 0)))):
        with pytest.raises(ModelError) as trained:
            choose_precision("int8", device, "train", probe)
        assert "train at auto, fp32 or bf16" in str(trained.value)
    # inference on CUDA (eval, tradeoff): int8 runs on the CPU, so say how to get there
    with pytest.raises(ModelError) as inferred:
        choose_precision("int8", CUDA, "infer", _probe(_gpu(9, 0)))
    message = str(inferred.value)
    assert "--device cpu" in message and "fp32, bf16 or fp16 on CUDA" in message
    assert "train" not in message


def test_auto_never_picks_int8_but_int8_is_native_with_vnni() -> None:
    hardware = _cpu("avx512_vnni")
    assert choose_precision("auto", CPU, "infer", _probe(hardware)).precision == "fp32"
    decision = choose_precision("int8", CPU, "infer", _probe(hardware))
    assert decision.precision == "int8" and not decision.emulated
    assert "avx512_vnni" in decision.reason


def test_decision_record_is_json_ready() -> None:
    decision = choose_precision("auto", CPU, "infer", _probe(_cpu("avx512_bf16")), _speed(2.0))
    record = decision.as_dict()
    assert record["precision"] == "bf16" and record["requested"] == "auto"
    assert record["native"] == ["bf16", "fp32"]
    assert decision.summary().startswith("precision bf16 (auto): ")


def test_read_cpu_flags_parses_x86_and_arm(tmp_path: Path) -> None:
    x86 = tmp_path / "x86"
    x86.write_text(
        "processor\t: 0\nmodel name\t: Example EPYC\nflags\t\t: fpu avx512f avx512_bf16\n\n"
        "processor\t: 1\nmodel name\t: Example EPYC\nflags\t\t: fpu avx512f avx512_bf16\n"
    )
    name, flags, source = read_cpu_flags(x86)
    assert name == "Example EPYC" and "avx512_bf16" in flags and source == str(x86)
    arm = tmp_path / "arm"
    arm.write_text("processor\t: 0\nFeatures\t: fp asimd asimddp bf16 i8mm\n")
    assert native_precisions(Hardware("cpu", "arm", read_cpu_flags(arm)[1])) == (
        "int8",
        "bf16",
        "fp32",
    )
    name, flags, source = read_cpu_flags(tmp_path / "missing")
    assert flags == frozenset() and source == "no /proc/cpuinfo"


def test_probe_reads_cuda_capability_through_torch(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(torch.cuda, "get_device_capability", lambda index: (7, 5))
    monkeypatch.setattr(torch.cuda, "get_device_name", lambda index: "Mock T4")
    hardware = probe_hardware(CUDA)
    assert hardware.cuda_capability == (7, 5) and hardware.name == "Mock T4"
    assert choose_precision("auto", CUDA, "infer", probe_hardware).native == ("fp16", "fp32")


def test_probe_on_this_cpu_agrees_with_proc_cpuinfo() -> None:
    hardware = probe_hardware(CPU)
    cpuinfo = Path("/proc/cpuinfo")
    if not cpuinfo.exists():
        pytest.skip("no /proc/cpuinfo")
    bf16 = "avx512_bf16" in cpuinfo.read_text().split()
    assert ("bf16" in native_precisions(hardware)) == (
        bf16 or bool(hardware.cpu_flags & {"amx_bf16", "bf16"})
    )


@pytest.mark.parametrize(
    ("cap", "kept"),
    [
        (None, {"avx512_bf16", "amx_bf16"}),
        ("AVX512_CORE_VNNI", set()),
        ("AVX2", set()),
        ("AVX512_CORE_BF16", {"avx512_bf16"}),
        ("AVX512_CORE_AMX", {"avx512_bf16", "amx_bf16"}),
        ("ALL", {"avx512_bf16", "amx_bf16"}),
        ("NOT_AN_ISA", {"avx512_bf16", "amx_bf16"}),
    ],
)
def test_onednn_isa_cap_removes_the_bf16_it_turns_off(cap: str | None, kept: set[str]) -> None:
    flags = frozenset({"avx512f", "avx512_vnni", "avx512_bf16", "amx_bf16", "amx_int8"})
    capped, note = apply_isa_cap(flags, cap)
    assert capped & {"avx512_bf16", "amx_bf16"} == kept
    assert {"avx512f", "avx512_vnni", "amx_int8"} <= capped  # int8 runs in ONNX Runtime
    assert (note is None) == (kept == {"avx512_bf16", "amx_bf16"})


def test_probe_under_an_isa_cap_never_chooses_bf16(monkeypatch: pytest.MonkeyPatch) -> None:
    assert onednn_isa_cap({"DNNL_MAX_CPU_ISA": " avx512_core_vnni "}) == "AVX512_CORE_VNNI"
    assert onednn_isa_cap({}) is None
    monkeypatch.setenv("ONEDNN_MAX_CPU_ISA", "avx512_core_vnni")
    hardware = probe_hardware(CPU)
    assert not hardware.cpu_flags & {"avx512_bf16", "amx_bf16"}
    decision = choose_precision("auto", CPU, "train", probe_hardware)
    assert decision.precision == "fp32" and "bf16" not in decision.native
    if hardware.isa_cap:  # this CPU has native bf16: the reason names the cap
        assert "ONEDNN_MAX_CPU_ISA=AVX512_CORE_VNNI" in decision.reason

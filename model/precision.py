"""Which numeric precision to run at: the one the hardware does natively.

One decision for ``train``, ``eval``, ``tradeoff``, ``export`` and the
benchmarks: ``--precision auto|fp32|bf16|fp16|int8``. ``auto`` is the fastest
precision the device runs *natively*; a precision the device only emulates is
never chosen by ``auto`` (bf16 on a CPU without bf16 instructions is emulated
by oneDNN through fp32 conversions: a GEA training step measured 2.6x slower
than fp32 on an AVX-512 Xeon without ``avx512_bf16``). Native is not always
faster either (an Intel Xeon with ``avx512_bf16`` but no AMX ran the GEA in bf16 at 0.60x
fp32's speed), so on a CPU ``auto`` takes a native bf16 only after timing it
against fp32 (:mod:`lenspair.model.precision_measure`, :data:`BF16_MIN_SPEED`).

What counts as native:

* CPU, x86: bf16 with ``avx512_bf16`` or ``amx_bf16``; int8 with
  ``avx512_vnni``, ``avx_vnni`` or ``amx_int8``.
* CPU, Arm: bf16 with ``bf16``; int8 with ``asimddp`` or ``i8mm``.
* CUDA: fp16 from compute capability 7.0 (tensor cores), bf16 from 8.0.
* fp32 everywhere.

On CUDA ``auto`` is nevertheless fp32: measured on an H100 (``python -m
benchmarks.bench_training --device cuda``, docs/results/gpu_h100.md), these
networks are too small for tensor cores to win back autocast's casts. A GEA
540x360 frame took 3.7 ms at fp32, 5.0 ms at bf16 and 6.3 ms at fp16; a
training step (batch 8, crop 256) ran 43 steps/s at fp32, 38 at bf16 and 36
at fp16. ``--precision bf16|fp16`` still runs on request (larger networks or
batches may gain from it).

oneDNN, which runs PyTorch's CPU convolutions, can be told to use fewer
instructions than the CPU has (``ONEDNN_MAX_CPU_ISA``, or the older
``DNNL_MAX_CPU_ISA``). Under a cap below ``AVX512_CORE_BF16`` the probe drops
the bf16 flags, because oneDNN then emulates bf16: on an AMD EPYC with
``avx512_bf16``, ``ONEDNN_MAX_CPU_ISA=AVX512_CORE_VNNI`` made a bf16 3x3
convolution 2.7x slower than fp32 instead of 2x faster, the ratio measured on
the Xeon without ``avx512_bf16`` (``python -m benchmarks.bench_isa_cap``).
This is also how to run lenspair on a bf16 CPU as it runs on one without
(the precision reason, printed once and kept in the run's config and the
demo report, names the cap). The int8 flags stay: the int8 path runs in
ONNX Runtime, which does not read the cap.

The flags come from ``/proc/cpuinfo`` (Linux). Elsewhere (macOS, Windows) no
flag list is read, so bf16 and int8 count as not native and ``auto`` stays
at fp32, which is never emulated; ``--precision bf16`` still runs on request.
``torch.ops.mkldnn._is_mkldnn_bf16_supported()`` is not used: it answers
True on CPUs that only emulate bf16.

``auto`` never picks int8: quantisation changes the output (see ``lenspair
export --int8``) and needs calibration images, so it is a deployment choice,
measured with ``eval --precision int8`` and the tradeoff's int8 row. For
training, int8 is refused; for inference on CUDA too (it runs in ONNX Runtime
on the CPU: the message points to ``--device cpu``); fp16 on the CPU is refused
(no fast CPU fp16 kernels in PyTorch: even on a Xeon with ``avx512_fp16``, a
Sapphire Rapids, GEA 540x360 took about 1.5x fp32's time at fp16, autocast or
fp16 weights, where bf16 on its AMX took about half).
"""

import os
import platform
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import torch

from lenspair.model.errors import ModelError
from lenspair.model.precision_measure import TIMED, Task, measured_bf16_speed

Precision = Literal["fp32", "bf16", "fp16", "int8"]
PRECISIONS: tuple[str, ...] = ("fp32", "bf16", "fp16", "int8")
CHOICES: tuple[str, ...] = ("auto", *PRECISIONS)

CPU_BF16_FLAGS = frozenset({"avx512_bf16", "amx_bf16", "bf16"})
"""``/proc/cpuinfo`` flags that mean bf16 arithmetic in hardware (x86 and Arm)."""
CPU_INT8_FLAGS = frozenset({"avx512_vnni", "avx_vnni", "amx_int8", "asimddp", "i8mm"})
"""``/proc/cpuinfo`` flags that mean int8 dot products in hardware (x86 and Arm)."""


@dataclass(frozen=True)
class Hardware:
    """What a device can do, as the probe saw it.

    Attributes:
        kind: ``cpu`` or ``cuda``.
        name: CPU model or CUDA device name.
        cpu_flags: CPU feature flags (empty when unknown or for CUDA).
        flags_source: where ``cpu_flags`` came from (``/proc/cpuinfo`` or a
            note that nothing was read).
        cuda_capability: ``(major, minor)`` for CUDA, else ``None``.
        isa_cap: what oneDNN's ISA cap took out of ``cpu_flags`` (empty: nothing;
            :func:`apply_isa_cap`).

    """

    kind: str
    name: str
    cpu_flags: frozenset[str] = frozenset()
    flags_source: str = ""
    cuda_capability: tuple[int, int] | None = None
    isa_cap: str = ""


Probe = Callable[[torch.device], Hardware]
Bf16Speed = Callable[[Task], float]
"""bf16's speed as a multiple of fp32's on this CPU, for a task (measured; mocked in tests)."""

BF16_MIN_SPEED = 1.1
"""``auto`` takes a native bf16 on the CPU only where it measured at least this x fp32's speed.

The margin keeps a CPU where the two run alike from flipping between runs;
measured ratios sit far from it (AMD Zen 5 about 2x, an Intel Xeon without
AMX 0.6x, :mod:`lenspair.model.precision_measure`).
"""


@dataclass(frozen=True)
class PrecisionDecision:
    """The precision a run uses and why.

    Attributes:
        precision: ``fp32``, ``bf16``, ``fp16`` or ``int8``.
        requested: what the user asked for (``auto`` or a precision).
        reason: one sentence, printed once and written into the run's config.
        native: the precisions the device runs natively, fastest first.
        device: the device the decision is for (``cpu``, ``cuda:0``).
        hardware: CPU model or CUDA device name.
        bf16_speed: bf16's measured speed as a multiple of fp32's, where
            ``auto`` measured it (a CPU with native bf16), else ``None``.

    """

    precision: str
    requested: str
    reason: str
    native: tuple[str, ...]
    device: str
    hardware: str
    bf16_speed: float | None = None

    @property
    def autocast_dtype(self) -> torch.dtype | None:
        """The autocast dtype (``None`` for fp32 and int8)."""
        return {"bf16": torch.bfloat16, "fp16": torch.float16}.get(self.precision)

    @property
    def emulated(self) -> bool:
        """Whether the chosen precision is not native on the device (slow)."""
        return self.precision not in self.native

    def summary(self) -> str:
        """``precision bf16 (auto): REASON``: the line printed once per run."""
        return f"precision {self.precision} ({self.requested}): {self.reason}"

    def as_dict(self) -> dict[str, object]:
        """JSON-ready record (for run configs, reports and benchmarks)."""
        return {
            "precision": self.precision,
            "requested": self.requested,
            "reason": self.reason,
            "native": list(self.native),
            "device": self.device,
            "hardware": self.hardware,
            "bf16_speed": self.bf16_speed,
        }


def read_cpu_flags(cpuinfo: Path = Path("/proc/cpuinfo")) -> tuple[str, frozenset[str], str]:
    """``(model name, flags, source)`` of this CPU from ``/proc/cpuinfo``.

    x86 lists ``flags``, Arm ``Features``. Where the file does not exist or
    cannot be read (macOS, Windows), the flags are empty and the source says
    so: bf16/int8 then count as not native.
    """
    try:
        text = cpuinfo.read_text()
    except OSError:
        return platform.processor() or platform.machine(), frozenset(), "no /proc/cpuinfo"
    name, flags = platform.machine(), frozenset[str]()
    for line in text.splitlines():
        key, _, value = line.partition(":")
        key = key.strip().lower()
        if key == "model name" and name == platform.machine():
            name = value.strip()
        elif key in ("flags", "features") and not flags:
            flags = frozenset(value.split())
    return name, flags, str(cpuinfo)


ONEDNN_ISA_ORDER: tuple[str, ...] = (
    "SSE41",
    "AVX",
    "AVX2",
    "AVX2_VNNI",
    "AVX2_VNNI_2",
    "AVX512_CORE",
    "AVX512_CORE_VNNI",
    "AVX512_CORE_BF16",
    "AVX512_CORE_FP16",
    "AVX10_1_512",
    "AVX512_CORE_AMX",
    "AVX10_1_512_AMX",
    "AVX512_CORE_AMX_FP16",
    "AVX10_1_512_AMX_FP16",
    "ALL",
)
"""oneDNN's x86 ISA cap values, lowest first (``ONEDNN_MAX_CPU_ISA``)."""


def onednn_isa_cap(environ: Mapping[str, str] = os.environ) -> str | None:
    """The oneDNN ISA cap set in the environment (upper case), or None."""
    for variable in ("ONEDNN_MAX_CPU_ISA", "DNNL_MAX_CPU_ISA"):
        value = environ.get(variable, "").strip().upper()
        if value:
            return value
    return None


def apply_isa_cap(flags: frozenset[str], cap: str | None) -> tuple[frozenset[str], str | None]:
    """``(flags, note)``: ``flags`` without the bf16 ones that oneDNN may not use under ``cap``.

    Below ``AVX512_CORE_BF16`` no bf16 instruction is used; below the AMX
    caps no AMX. An unknown cap (oneDNN ignores it) or none changes nothing.
    """
    if cap is None or cap not in ONEDNN_ISA_ORDER:
        return flags, None
    rank = ONEDNN_ISA_ORDER.index(cap)
    dropped = set()
    if rank < ONEDNN_ISA_ORDER.index("AVX512_CORE_BF16"):
        dropped |= {"avx512_bf16", "amx_bf16"}
    elif rank < ONEDNN_ISA_ORDER.index("AVX512_CORE_AMX"):
        dropped |= {"amx_bf16"}
    removed = sorted(flags & dropped)
    if not removed:
        return flags, None
    return flags - dropped, f"ONEDNN_MAX_CPU_ISA={cap} turns off {', '.join(removed)}"


def probe_hardware(device: torch.device) -> Hardware:
    """Read the capabilities of ``device`` (CPU flags, under oneDNN's ISA cap; CUDA capability)."""
    if device.type == "cuda":
        index = device.index if device.index is not None else torch.cuda.current_device()
        major, minor = torch.cuda.get_device_capability(index)
        return Hardware("cuda", torch.cuda.get_device_name(index), cuda_capability=(major, minor))
    name, flags, source = read_cpu_flags()
    flags, note = apply_isa_cap(flags, onednn_isa_cap())
    return Hardware("cpu", name, flags, source, isa_cap=note or "")


def native_precisions(hardware: Hardware) -> tuple[str, ...]:
    """Precisions ``hardware`` runs natively, fastest first (fp32 always last)."""
    if hardware.kind == "cuda":
        major, minor = hardware.cuda_capability or (0, 0)
        native = []
        if (major, minor) >= (8, 0):
            native.append("bf16")
        if (major, minor) >= (7, 0):
            native.append("fp16")
        return (*native, "fp32")
    native = []
    if hardware.cpu_flags & CPU_INT8_FLAGS:
        native.append("int8")
    if hardware.cpu_flags & CPU_BF16_FLAGS:
        native.append("bf16")
    return (*native, "fp32")


def _why_native(hardware: Hardware, precision: str) -> str:
    if hardware.kind == "cuda":
        major, minor = hardware.cuda_capability or (0, 0)
        return f"compute capability {major}.{minor}"
    wanted = CPU_BF16_FLAGS if precision == "bf16" else CPU_INT8_FLAGS
    found = sorted(hardware.cpu_flags & wanted)
    return "CPU flag " + ", ".join(found) if found else "no CPU flag"


def measure_bf16_speed(task: Task) -> float:
    """bf16's speed as a multiple of fp32's on this CPU for ``task``, under oneDNN's ISA cap.

    Timed once per process, task, thread count and cap
    (:func:`lenspair.model.precision_measure.measured_bf16_speed`).
    """
    return measured_bf16_speed(task, torch.get_num_threads(), onednn_isa_cap())


def choose_precision(
    requested: str,
    device: torch.device,
    task: Task,
    probe: Probe = probe_hardware,
    bf16_speed: Bf16Speed | None = None,
) -> PrecisionDecision:
    """Resolve ``--precision`` for ``device`` and ``task``.

    On a CPU with native bf16, ``auto`` times bf16 against fp32 first
    (``bf16_speed``) and keeps fp32 unless bf16 measured at least
    :data:`BF16_MIN_SPEED` x its speed: a flag says the instructions exist,
    not that they are faster (:mod:`lenspair.model.precision_measure`).

    Args:
        requested: ``auto``, ``fp32``, ``bf16``, ``fp16`` or ``int8``.
        device: where the run computes.
        task: ``train`` (autocast training) or ``infer`` (eval, tradeoff, export).
        probe: reads the hardware (mocked in tests).
        bf16_speed: measures bf16's speed against fp32's (default
            :func:`measure_bf16_speed`; mocked in tests).

    Returns:
        The decision with its reason and the native set.

    Raises:
        ModelError: an unknown precision, fp16 on the CPU, or int8 for
            training or on CUDA.

    """
    if requested not in CHOICES:
        raise ModelError(f"--precision: expected one of {', '.join(CHOICES)}, got {requested!r}")
    hardware = probe(device)
    native = native_precisions(hardware)
    where = f"{hardware.name} ({device.type})"
    if requested == "auto":
        candidates = [p for p in native if p != "int8"]
        precision = "fp32" if hardware.kind == "cuda" else candidates[0]
        measure = bf16_speed or measure_bf16_speed
        speed = measure(task) if precision == "bf16" else None
        if speed is not None and speed < BF16_MIN_SPEED:
            precision = "fp32"
            reason = (
                f"auto: fp32 on {where}: bf16 is native ({_why_native(hardware, 'bf16')}) but "
                f"measured {speed:.2f}x fp32's speed here ({TIMED[task]}; bf16 needs "
                f"{BF16_MIN_SPEED}x)"
            )
        elif precision == "bf16":
            reason = (
                f"auto: fastest native precision on {where} ({_why_native(hardware, 'bf16')}; "
                f"measured {speed:.2f}x fp32's speed, {TIMED[task]})"
            )
        elif hardware.kind == "cuda":
            reason = f"auto: fp32 on {where}: " + (
                "measured on an H100, this network runs faster at fp32 than with "
                "bf16/fp16 autocast (too small for tensor cores to repay the casts)"
                if len(native) > 1
                else "no tensor-core fp16/bf16"
            )
        elif not hardware.cpu_flags:
            reason = f"auto: CPU flags unknown ({hardware.flags_source}); fp32 is never emulated"
        else:
            reason = f"auto: bf16 is not native on {where} (emulated bf16 is slower than fp32)"
            if hardware.isa_cap:
                reason += f"; {hardware.isa_cap}"
        return PrecisionDecision(
            precision, requested, reason, native, str(device), hardware.name, speed
        )
    if requested == "fp16" and device.type == "cpu":
        raise ModelError("precision fp16 runs on CUDA only; on the CPU use bf16 or fp32")
    if requested == "int8" and task == "train":
        raise ModelError(
            "precision int8 is for CPU inference (an ONNX Runtime quantised model); "
            "train at auto, fp32 or bf16"
        )
    if requested == "int8" and device.type == "cuda":
        # an inference caller (eval, tradeoff): the same network can run int8 on the CPU
        raise ModelError(
            "precision int8 is for CPU inference (an ONNX Runtime quantised model); "
            "use --device cpu for int8, or fp32, bf16 or fp16 on CUDA"
        )
    if requested in native:
        reason = f"requested; native on {where}"
        if requested != "fp32":
            reason += f" ({_why_native(hardware, requested)})"
    else:
        reason = f"requested; NOT native on {where}: emulated, expect it to be slower than fp32"
    return PrecisionDecision(requested, requested, reason, native, str(device), hardware.name)

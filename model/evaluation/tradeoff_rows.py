"""The rows of the accuracy/time trade-off table and their Pareto marking.

Shared by :mod:`lenspair.model.evaluation.tradeoff` (which measures the rows)
and :mod:`lenspair.model.evaluation.tradeoff_report` (which writes them), so
that neither imports the other's caller.
"""

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace


@dataclass(frozen=True)
class TradeoffRow:
    """One line of the table: a checkpoint at one precision."""

    name: str
    variant: str
    width: float
    num_blocks: int
    precision: str
    params: int
    gflops: float
    cpu_ms: float | None
    gpu_ms: float | None
    psnr_db: float
    ssim: float
    convention: str
    steps: int
    pareto_psnr: bool = False
    pareto_ssim: bool = False
    psnr_vs_fp32_db: float | None = None
    scored_step: int | None = None

    def precision_label(self) -> str:
        """``int8 (41.20 dB vs fp32)``: a reduced precision with its agreement with fp32."""
        if self.psnr_vs_fp32_db is None:
            return self.precision
        return f"{self.precision} ({self.psnr_vs_fp32_db:.2f} dB vs fp32)"

    def describe(self) -> str:
        """The row as one line for a log: name, precision, accuracy and its time."""
        times = [
            f"{device} {ms:.1f} ms"
            for device, ms in (("CPU", self.cpu_ms), ("GPU", self.gpu_ms))
            if ms is not None
        ]
        steps = f"{self.steps} step{'' if self.steps == 1 else 's'}"
        return (
            f"{self.name} {self.precision_label()}: PSNR {self.psnr_db:.2f} dB, SSIM "
            f"{self.ssim:.4f} ({self.convention}, {steps}); "
            f"{', '.join(times) or 'not timed'} per frame"
        )


def pareto_front(times: Sequence[float | None], scores: Sequence[float]) -> list[int]:
    """Indices of the points no other point dominates (faster-or-equal and better-or-equal).

    A point with an unknown (``None``) or NaN time or a NaN score is never on
    the front. Points that tie exactly are all on it. Returned in index order.
    """
    valid = [
        i
        for i, (t, s) in enumerate(zip(times, scores, strict=True))
        if t is not None and not math.isnan(t) and not math.isnan(s)
    ]
    front = []
    for i in valid:
        ti, si = times[i], scores[i]
        assert ti is not None
        dominated = False
        for j in valid:
            tj, sj = times[j], scores[j]
            assert tj is not None
            if tj <= ti and sj >= si and (tj < ti or sj > si):
                dominated = True
                break
        if not dominated:
            front.append(i)
    return front


def mark_pareto(
    rows: Sequence[TradeoffRow], baseline: tuple[float, float] | None = None
) -> list[TradeoffRow]:
    """Set ``pareto_psnr``/``pareto_ssim`` against CPU time.

    Args:
        rows: the table's rows.
        baseline: the input's ``(PSNR, SSIM)`` without restoration: a choice
            that takes no time, so a row it beats is on no front (it is not a
            row itself and is never marked).
    """
    times: list[float | None] = [r.cpu_ms for r in rows]
    psnrs, ssims = [r.psnr_db for r in rows], [r.ssim for r in rows]
    if baseline is not None:
        times, psnrs, ssims = [*times, 0.0], [*psnrs, baseline[0]], [*ssims, baseline[1]]
    on_psnr = set(pareto_front(times, psnrs)) - {len(rows)}
    on_ssim = set(pareto_front(times, ssims)) - {len(rows)}
    return [
        replace(r, pareto_psnr=i in on_psnr, pareto_ssim=i in on_ssim) for i, r in enumerate(rows)
    ]

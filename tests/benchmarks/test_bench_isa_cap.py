"""The ISA-cap benchmark's child processes see the cap they are given."""

from benchmarks.bench_isa_cap import measure


def test_capped_child_never_trains_at_bf16_and_reports_both_timings() -> None:
    capped = measure(runs=1, cap="AVX512_CORE_VNNI")
    assert capped["auto"] == "fp32"
    medians = capped["median_ms"]
    assert isinstance(medians, dict) and set(medians) == {"fp32", "bf16"}
    assert all(value > 0 for value in medians.values())

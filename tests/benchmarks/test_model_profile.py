"""The DeRaindrop stand-in has the published size; the profile accounts for the time."""

import torch

from benchmarks.deraindrop import DeRaindropGenerator
from benchmarks.model_profile import layer_profile, profile_table
from lenspair.model.networks.variants import build_model


def test_deraindrop_generator_has_the_published_size_and_outputs() -> None:
    network = DeRaindropGenerator().eval()
    assert round(sum(p.numel() for p in network.parameters()) / 1e6, 2) == 6.24
    with torch.inference_mode():
        masks, quarter, half, restored = network(torch.rand(1, 3, 32, 48))
    assert len(masks) == 4 and masks[-1].shape == (1, 1, 32, 48)
    assert quarter.shape == (1, 3, 8, 12) and half.shape == (1, 3, 16, 24)
    assert restored.shape == (1, 3, 32, 48)


def test_layer_profile_names_the_convolutions_and_shares_sum_below_one() -> None:
    torch.manual_seed(0)
    model = build_model("GEA", 1, width=0.25, num_blocks=1).eval()
    image = torch.rand(1, 1, 32, 48)
    with torch.inference_mode():
        rows = layer_profile(lambda: model(image), runs=2, top=50)
    assert rows and all(0.0 <= float(r["share"]) <= 1.0 for r in rows)  # type: ignore[arg-type]
    assert sum(float(r["share"]) for r in rows) <= 1.0 + 1e-6  # type: ignore[arg-type]
    assert any("conv" in str(r["op"]) for r in rows)
    assert "| op | input shapes |" in profile_table(rows)

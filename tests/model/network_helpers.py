"""Helpers shared by the network tests."""

import torch


def randomise(module: torch.nn.Module, seed: int = 1, scale: float = 0.1) -> None:
    """Give every parameter ``scale * N(0, 1)`` values (heads start at zero, i.e. identity)."""
    generator = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for parameter in module.parameters():
            parameter.copy_(scale * torch.randn(parameter.shape, generator=generator))

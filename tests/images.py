"""Synthetic test images shared by the geometry tests."""

import cv2
import numpy as np


def texture(shape: tuple[int, int], seed: int) -> np.ndarray:
    """Multi-scale noise in [0, 1], float32: corners and edges at every scale."""
    rng = np.random.default_rng(seed)
    image = np.zeros(shape, np.float32)
    for sigma, amplitude in [(1.0, 0.25), (3.0, 0.35), (8.0, 0.5), (25.0, 0.6)]:
        noise = cv2.GaussianBlur(rng.standard_normal(shape).astype(np.float32), (0, 0), sigma)
        image += amplitude * noise / noise.std()
    return (image - image.min()) / (image.max() - image.min())

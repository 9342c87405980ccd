"""Rig trajectory and the recording clock (timestamps, jitter, dropped frames).

Poses are ``T_world_body`` (4x4, metres): the body frame is cam0's frame and
the world frame is the body frame at the first frame, before the start
offset ``start_m`` (see :class:`lenspair.simulate.spec.MotionSpec` for the formula).
"""

from dataclasses import dataclass

import numpy as np

from lenspair.simulate.spec import MotionSpec, RecordingSpec
from lenspair.simulate.transforms import make_transform, rotation_x, rotation_y, rotation_z


def body_pose(motion: MotionSpec, seconds: float) -> np.ndarray:
    """``T_world_body`` at ``seconds`` after the first frame (float64 4x4)."""
    omega = 2.0 * np.pi * motion.frequency_hz
    yaw = np.deg2rad(motion.yaw_amplitude_deg) * np.sin(omega * seconds)
    pitch = np.deg2rad(motion.pitch_amplitude_deg) * np.sin(2.0 * omega * seconds)
    roll = np.deg2rad(motion.roll_amplitude_deg) * np.sin(3.0 * omega * seconds)
    rotation = rotation_y(yaw) @ rotation_x(pitch) @ rotation_z(roll)
    centre = np.asarray(motion.start_m) + np.asarray(motion.velocity_mps) * seconds
    return make_transform(rotation, centre)


@dataclass(frozen=True)
class Clock:
    """Timestamps and drops of both cameras.

    Attributes:
        nominal_ns: ``(F,)`` int64 nominal frame times.
        stamps_ns: ``(F, 2)`` int64 actual times of cam0 and cam1 (nominal
            plus each camera's own jitter).
        dropped: ``(F, 2)`` bool, True where that camera's frame is missing.

    """

    nominal_ns: np.ndarray
    stamps_ns: np.ndarray
    dropped: np.ndarray


def make_clock(recording: RecordingSpec, rng: np.random.Generator) -> Clock:
    """Draw the recording clock.

    Jitter is Gaussian with standard deviation ``jitter_us``, clipped at
    3 sigma (less than a quarter period, so timestamps stay increasing);
    drops are independent per camera and frame.
    """
    frames = recording.frames
    offsets = np.rint(np.arange(frames, dtype=np.float64) * (1e9 / recording.rate_hz))
    nominal = recording.start_ns + offsets.astype(np.int64)
    sigma_ns = recording.jitter_us * 1e3
    jitter = np.clip(rng.normal(0.0, 1.0, size=(frames, 2)), -3.0, 3.0) * sigma_ns
    stamps = nominal[:, None] + np.rint(jitter).astype(np.int64)
    dropped = rng.random(size=(frames, 2)) < np.asarray(recording.drop_probability)[None, :]
    return Clock(nominal_ns=nominal, stamps_ns=stamps, dropped=dropped)

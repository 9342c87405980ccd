"""The simulated stereo rig: camera models and mounting from a :class:`RigSpec`.

The body frame is cam0's frame. ``T_cam1_cam0`` (Kalibr's ``T_cn_cnm1``)
holds cam1's mounting, including the 180 deg rotation about its optical axis
when ``cam1_rotated_180`` is set; nothing else special-cases that mounting.
"""

import numpy as np

from lenspair.rectify.rig import CameraModel, StereoRig
from lenspair.simulate.rigspec import CameraSpec, RigSpec
from lenspair.simulate.transforms import invert_transform, make_transform, rotation_xyz_deg

ROTATED_180 = np.diag([-1.0, -1.0, 1.0])
"""Exact rotation by 180 deg about the optical (z) axis."""


def camera_model(spec: CameraSpec) -> CameraModel:
    """The :class:`CameraModel` of a :class:`CameraSpec`."""
    return CameraModel(spec.intrinsics, spec.distortion_model, spec.distortion, spec.resolution)


def rig_from_spec(spec: RigSpec) -> StereoRig:
    """Build the true :class:`StereoRig` (what ``camchain.yaml`` records).

    cam1's centre is ``baseline_m`` along ``baseline_direction`` in cam0's
    frame, and its orientation in cam0's frame is ``R_mis @ Rz(180)`` (rotated
    mounting) or ``R_mis``.
    """
    direction = np.asarray(spec.baseline_direction, dtype=np.float64)
    direction = direction / np.abs(direction).max()  # first: the length of 1e308s overflows
    centre = spec.baseline_m * direction / np.linalg.norm(direction)
    R_cam0_cam1 = rotation_xyz_deg(spec.cam1_rotation_deg)
    if spec.cam1_rotated_180:
        R_cam0_cam1 = R_cam0_cam1 @ ROTATED_180
    T_cam1_cam0 = invert_transform(make_transform(R_cam0_cam1, centre))
    # Round-off residue (1e-20 instead of 0) would only clutter the YAML files.
    T_cam1_cam0[np.abs(T_cam1_cam0) < 1e-15] = 0.0
    return StereoRig(camera_model(spec.cam0), camera_model(spec.cam1), T_cam1_cam0)


def body_from_cameras(rig: StereoRig) -> tuple[np.ndarray, np.ndarray]:
    """``(T_body_cam0, T_body_cam1)``: EuRoC's ``T_BS`` of each camera (body = cam0)."""
    return np.eye(4), invert_transform(rig.T_cam1_cam0)

"""The stereo rig the rectify tests calibrate, rectify and write: one definition."""

import cv2
import numpy as np

from lenspair.rectify.rig import CameraModel, DistortionModel, StereoRig

DISTORTION = {
    "radtan": ((-0.28, 0.07, 0.0005, -0.0003), (-0.27, 0.065, -0.0004, 0.0002)),
    "equidistant": ((0.01, -0.002, 0.001, -0.0005), (0.012, -0.001, 0.0005, -0.0003)),
}


def make_rig(model: DistortionModel = "radtan", rotated: bool = False) -> StereoRig:
    """An Alphasense-like rig: f ~ 350 px, 720x540, B = 0.11 m; cam1 upside down if rotated."""
    d0, d1 = DISTORTION[model]
    cam0 = CameraModel((350.0, 351.0, 360.0, 270.0), model, d0, (720, 540))
    cam1 = CameraModel((352.0, 352.5, 358.0, 271.0), model, d1, (720, 540))
    R = cv2.Rodrigues(np.array([0.01, -0.02, 0.005]))[0]
    if rotated:
        R = np.diag([-1.0, -1.0, 1.0]) @ R
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = -R @ np.array([0.11, 0.002, -0.001])
    return StereoRig(cam0, cam1, T)

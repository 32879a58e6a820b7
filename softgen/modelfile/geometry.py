"""Numeric frame geometry shared by the model readers and the symbolic layer."""
from __future__ import annotations

import numpy as np


def rpy(r: float, p: float, y: float) -> np.ndarray:
    """Rotation of fixed-axis roll, pitch, yaw (URDF ``<origin rpy>``): R = Rz(y) Ry(p) Rx(r)."""
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])

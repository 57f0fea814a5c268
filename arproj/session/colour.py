"""How different two colours look: CIELAB (D65, sRGB) and the CIEDE2000 colour difference ΔE₀₀.

ΔE₀₀ ≈ 1 is the smallest difference an observer sees side by side; colours that must never be taken for one
another on a projected wall are kept tens of units apart (overlays' verdict colours from the class colours).
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray


def srgb_to_lab(rgb: ArrayLike) -> NDArray[np.float64]:
    """(..., 3) sRGB 0..255 → (..., 3) CIELAB (L* 0..100), D65 white."""
    arr = np.asarray(rgb, dtype=np.float32) / np.float32(255.0)
    shape = arr.shape
    lab = cv2.cvtColor(np.ascontiguousarray(arr.reshape(-1, 1, 3)), cv2.COLOR_RGB2Lab)
    return lab.reshape(shape).astype(np.float64)


def delta_e2000(rgb_a: ArrayLike, rgb_b: ArrayLike) -> NDArray[np.float64]:
    """CIEDE2000 difference between sRGB colours (..., 3) 0..255 (broadcast)."""
    return delta_e2000_lab(srgb_to_lab(rgb_a), srgb_to_lab(rgb_b))


def delta_e2000_lab(lab_a: ArrayLike, lab_b: ArrayLike) -> NDArray[np.float64]:
    """CIEDE2000 difference between CIELAB colours (..., 3) (broadcast), after Sharma, Wu & Dalal (2005)."""
    L1, a1, b1 = np.moveaxis(np.asarray(lab_a, dtype=np.float64), -1, 0)
    L2, a2, b2 = np.moveaxis(np.asarray(lab_b, dtype=np.float64), -1, 0)
    c_mean = 0.5 * (np.hypot(a1, b1) + np.hypot(a2, b2))
    g = 0.5 * (1.0 - np.sqrt(c_mean**7 / (c_mean**7 + 25.0**7)))
    a1p, a2p = (1.0 + g) * a1, (1.0 + g) * a2
    c1p, c2p = np.hypot(a1p, b1), np.hypot(a2p, b2)
    h1p = np.degrees(np.arctan2(b1, a1p)) % 360.0
    h2p = np.degrees(np.arctan2(b2, a2p)) % 360.0
    dLp = L2 - L1
    dCp = c2p - c1p
    dh = h2p - h1p
    dh = np.where(dh > 180.0, dh - 360.0, np.where(dh < -180.0, dh + 360.0, dh))
    dh = np.where(c1p * c2p == 0, 0.0, dh)
    dHp = 2.0 * np.sqrt(c1p * c2p) * np.sin(np.radians(dh / 2.0))
    Lp = 0.5 * (L1 + L2)
    Cp = 0.5 * (c1p + c2p)
    hsum = h1p + h2p
    hp = np.where(np.abs(h1p - h2p) > 180.0, np.where(hsum < 360.0, hsum + 360.0, hsum - 360.0), hsum) / 2.0
    hp = np.where(c1p * c2p == 0, hsum, hp)
    t = (1.0 - 0.17 * np.cos(np.radians(hp - 30.0)) + 0.24 * np.cos(np.radians(2.0 * hp))
         + 0.32 * np.cos(np.radians(3.0 * hp + 6.0)) - 0.20 * np.cos(np.radians(4.0 * hp - 63.0)))
    d_theta = 30.0 * np.exp(-(((hp - 275.0) / 25.0) ** 2))
    rc = 2.0 * np.sqrt(Cp**7 / (Cp**7 + 25.0**7))
    sl = 1.0 + 0.015 * (Lp - 50.0) ** 2 / np.sqrt(20.0 + (Lp - 50.0) ** 2)
    sc = 1.0 + 0.045 * Cp
    sh = 1.0 + 0.015 * Cp * t
    rt = -np.sin(np.radians(2.0 * d_theta)) * rc
    return np.sqrt((dLp / sl) ** 2 + (dCp / sc) ** 2 + (dHp / sh) ** 2 + rt * (dCp / sc) * (dHp / sh))

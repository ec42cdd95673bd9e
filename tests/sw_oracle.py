"""Independent reference: the Sliding Window algorithm, brute force in NumPy float64.

Written from the paper's definition, sharing no code with the C kernels: for each new
sample n the segment from the anchor a to n is the straight line through both; if the sum
of squared residuals of the samples a < i < n exceeds the threshold, or the segment would
cover more than max_len samples, sample n-1 becomes a segment point and the new anchor.
"""
from __future__ import annotations

import numpy as np


def sliding_window(t: np.ndarray, y: np.ndarray, threshold: float, max_len: int = 1000) -> np.ndarray:
    """Segment-point indices (K,) int64 of (t (m,), y (m, D)), first and last sample included."""
    t = np.asarray(t, np.float64)
    y = np.asarray(y, np.float64).reshape(len(t), -1)
    points = [0]
    anchor = 0
    for n in range(1, len(t)):
        if n - 1 - anchor >= max_len:
            split = True
        else:
            t_rel = t[anchor + 1 : n] - t[anchor]
            y_rel = y[anchor + 1 : n] - y[anchor]
            slope = (y[n] - y[anchor]) / (t[n] - t[anchor])
            ssr = np.sum((y_rel - t_rel[:, None] * slope) ** 2)
            split = ssr > threshold
        if split:
            points.append(n - 1)
            anchor = n - 1
    if len(t) and points[-1] != len(t) - 1:
        points.append(len(t) - 1)
    return np.asarray(points, np.int64)

"""Smooth space curves for swept tubes: Catmull-Rom splines resampled at even arc length."""

from __future__ import annotations

import numpy as np


def catmull_rom(control: np.ndarray, samples_per_span: int = 16) -> np.ndarray:
    """A centripetal Catmull-Rom spline through every control point, as a dense (K, 3) polyline.

    Centripetal parametrisation avoids the cusps and self-loops that the uniform form makes on
    uneven spacing.
    """
    p = np.asarray(control, dtype=np.float64)
    if len(p) < 2:
        raise ValueError("a spline needs at least two control points")
    # Mirrored end points make the curve start and end at the first and last control points.
    p = np.vstack([2 * p[0] - p[1], p, 2 * p[-1] - p[-2]])
    t = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1) ** 0.5)])
    t = np.maximum.accumulate(t + np.arange(len(t)) * 1e-9)  # repeated points must not divide by 0
    u = np.linspace(0.0, 1.0, samples_per_span, endpoint=False)[:, None]
    spans = []
    for i in range(1, len(p) - 2):
        t0, t1, t2, t3 = t[i - 1 : i + 3]
        tt = t1 + u * (t2 - t1)
        a1 = ((t1 - tt) * p[i - 1] + (tt - t0) * p[i]) / (t1 - t0)
        a2 = ((t2 - tt) * p[i] + (tt - t1) * p[i + 1]) / (t2 - t1)
        a3 = ((t3 - tt) * p[i + 1] + (tt - t2) * p[i + 2]) / (t3 - t2)
        b1 = ((t2 - tt) * a1 + (tt - t0) * a2) / (t2 - t0)
        b2 = ((t3 - tt) * a2 + (tt - t1) * a3) / (t3 - t1)
        spans.append(((t2 - tt) * b1 + (tt - t1) * b2) / (t2 - t1))
    spans.append(p[-2][None])
    return np.vstack(spans)


def resample(polyline: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """Points evenly spaced along the arc, at most `step` apart, and their arc lengths."""
    p = np.asarray(polyline, dtype=np.float64)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
    n = max(int(np.ceil(s[-1] / step)), 1) + 1
    target = np.linspace(0.0, s[-1], n)
    points = np.stack([np.interp(target, s, p[:, k]) for k in range(3)], axis=1)
    return points, target

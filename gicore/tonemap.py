"""The one tone map used everywhere (network I/O, metrics, previews).

Linear HDR radiance ``x >= 0`` maps to display values in ``[0, 1)`` by Reinhard compression followed by
a 2.2 display gamma::

    T(x) = (x / (1 + x)) ** (1 / 2.2)
    T^-1(y) = y**2.2 / (1 - y**2.2)

It is monotone and invertible on ``[0, inf)``; ``inverse`` clips ``y`` just below 1 so that values a
network produces at the top of its range stay finite. 8-bit display values (``round(255 T(x))``, what the 8-bit
codecs carry) decode through :func:`inverse_u8`, capped at the top bin's lower edge :data:`Y8_MAX`, by a table
(:func:`linear_of_display`). Networks work in ``[-1, 1]`` (tanh outputs):
``to_signed`` / ``from_signed`` convert. NaN or Inf anywhere is an upstream bug (a diverged network, a
broken render) and every function here rejects it rather than passing it on.
"""

from __future__ import annotations

import numpy as np

GAMMA = 2.2
#: Largest display value ``inverse`` accepts before clipping (maps to ~4e4 linear).
Y_MAX = 1.0 - 1e-5


def _finite(what: str, x: np.ndarray) -> np.ndarray:
    x = np.asarray(x)
    if not np.all(np.isfinite(x)):
        raise ValueError(f"{what} input contains NaN or Inf; check the renderer or network that produced it")
    return x


def tonemap(x: np.ndarray) -> np.ndarray:
    """Linear radiance (negative values clipped to 0) to display values in [0, 1)."""
    x = np.maximum(_finite("tonemap", x).astype(np.float32), 0.0)
    return (x / (1.0 + x)) ** (1.0 / GAMMA)


def inverse_tonemap(y: np.ndarray) -> np.ndarray:
    """Display values in [0, 1] back to linear radiance (exact inverse of :func:`tonemap`)."""
    y = np.clip(_finite("inverse_tonemap", y).astype(np.float32), 0.0, Y_MAX) ** GAMMA
    return y / (1.0 - y)


def to_signed(y: np.ndarray) -> np.ndarray:
    """[0, 1] display values to the [-1, 1] range of tanh outputs."""
    return 2.0 * y - 1.0


def from_signed(s: np.ndarray) -> np.ndarray:
    """[-1, 1] network values back to [0, 1] display values."""
    return np.clip((_finite("from_signed", s) + 1.0) * 0.5, 0.0, 1.0)


#: The largest display value an 8-bit value decodes to: the lower edge of the top bin (the top bin holds every
#: radiance from there to infinity).
Y8_MAX = 254.5 / 255.0


def inverse_u8(q: np.ndarray) -> np.ndarray:
    """The linear value of each 8-bit display value (the tone map's inverse, capped at :data:`Y8_MAX`)."""
    return inverse_tonemap(np.minimum(np.asarray(q).astype(np.float32) / 255.0, Y8_MAX)).astype(np.float32)


#: :func:`inverse_u8` of every byte: 8-bit decodes look their pixels up here (the formula per pixel was most of a
#: decode's time; each entry is the formula's own result, so the bits are the same).
LINEAR_OF_U8 = inverse_u8(np.arange(256, dtype=np.uint8))


def linear_of_display(q: np.ndarray) -> np.ndarray:
    """Linear radiance of 8-bit display values (uint8, any shape): :func:`inverse_u8` by its table."""
    if q.dtype != np.uint8:
        raise ValueError(f"8-bit display values are uint8, got {q.dtype}")
    return np.take(LINEAR_OF_U8, q)

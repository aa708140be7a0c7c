"""`bench quality`'s image grid (``quality_grid.png``, written by :func:`gicore.present.sheet.save_sheet`): per
frame, the inputs, each model's map and the GT, then each one's |error| and its low-frequency signed error, on
fixed scales with their legends."""

from __future__ import annotations

import numpy as np

from gicore.metrics import LF_SIGMA, lf_difference
from gicore.present.sheet import Cell

#: The grid's |error| images show |tone-mapped prediction − GT| times this gain (white from 1 / gain = 0.25 up).
GRID_ABS_GAIN = 4.0
#: The grid's low-frequency images map the blurred signed error (prediction − GT, channel mean) from
#: −GRID_LF_RANGE (blue: darker than GT) through 0 (white) to +GRID_LF_RANGE (red: brighter), clipped.
GRID_LF_RANGE = 0.1
GRID_LF_CMAP = "RdBu_r"

GRID_CAPTION = (  # ASCII: PIL's default font has no glyphs for sigma or the minus sign
    f"Per frame: row 1 inputs, maps, GT; row 2 |tone-mapped prediction - GT| x{GRID_ABS_GAIN:g} per channel (black 0, "
    f"full colour from {1 / GRID_ABS_GAIN:g}); row 3 Gaussian (sigma {LF_SIGMA:g} px) of the signed tone-mapped "
    "difference, "
    f"channel mean: blue -{GRID_LF_RANGE:g} (darker than GT), white 0, red +{GRID_LF_RANGE:g} (brighter), clipped. "
    "Under DI: DI alone's error. 'LF': that frame's lf_error."
)


def abs_error_image(prediction: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """|prediction - reference| per channel (both tone-mapped), times :data:`GRID_ABS_GAIN`, clipped to [0, 1]."""
    return np.clip(np.abs(prediction - reference) * GRID_ABS_GAIN, 0.0, 1.0)


def lf_colours(signed: np.ndarray) -> np.ndarray:
    """Signed values (any shape) as colours (shape + (3,)) of :data:`GRID_LF_CMAP` on ±:data:`GRID_LF_RANGE`,
    clipped."""
    from matplotlib import colormaps

    t = np.clip(0.5 + 0.5 * np.asarray(signed) / GRID_LF_RANGE, 0.0, 1.0)
    return np.asarray(colormaps[GRID_LF_CMAP](t))[..., :3]


def _legend(shape: tuple[int, ...], ramp: np.ndarray) -> np.ndarray:
    """A white cell with a horizontal colour ``ramp`` (Wx3) across its middle (its scale is written on it)."""
    h = shape[0]
    cell = np.ones(shape[:2] + (3,))
    cell[h // 3 : h * 2 // 3] = ramp[None]
    return cell


def grid_rows(
    frame: dict[str, np.ndarray], maps: dict[str, np.ndarray], reference: np.ndarray, title: str
) -> list[list[Cell]]:
    """The three grid rows of one frame: ``[DI, albedo, normal, models..., GT]``; then under DI and under each
    model its |error| image (:func:`abs_error_image`); then its low-frequency signed error (:func:`lf_colours`
    of :func:`gicore.metrics.lf_difference`'s channel mean) with the frame's lf_error written on it. Legends
    stand under albedo. ``maps``: tone-mapped, ``"di_only"`` (the DI input) and the models in column order;
    ``reference``: the tone-mapped GT."""
    blank: Cell = (np.ones_like(reference), "")
    models = [n for n in maps if n != "di_only"]
    signed = {n: lf_difference(maps[n], reference) for n in maps}
    abs_cells = {n: (abs_error_image(maps[n], reference), "|error|") for n in maps}
    lf_cells = {n: (lf_colours(d.mean(axis=-1)), f"LF {float(np.mean(np.abs(d))):.4f}") for n, d in signed.items()}
    x = np.linspace(0.0, 1.0, reference.shape[1])
    abs_legend = (
        _legend(reference.shape, np.repeat(x[:, None], 3, axis=1)),
        f"|error| x{GRID_ABS_GAIN:g}: 0 .. {1 / GRID_ABS_GAIN:g}+",
    )
    lf_legend = (
        _legend(reference.shape, lf_colours((2 * x - 1) * GRID_LF_RANGE)),
        f"LF signed: -{GRID_LF_RANGE:g} .. +{GRID_LF_RANGE:g}",
    )
    images = [(maps["di_only"], title), (frame["albedo"], ""), (frame["normal"] * 0.5 + 0.5, "")]
    return [
        images + [(maps[n], "") for n in models] + [(reference, "")],
        [abs_cells["di_only"], abs_legend, blank] + [abs_cells[n] for n in models] + [blank],
        [lf_cells["di_only"], lf_legend, blank] + [lf_cells[n] for n in models] + [blank],
    ]

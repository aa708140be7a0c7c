"""A sheet of images as one PNG: a header of column labels over a grid of equal cells, each cell's text drawn on it,
and a caption wrapped below (a bench's inputs, predictions and errors side by side, say)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

#: One cell of a sheet: an HxWx3 image in [0, 1] and the text drawn on it ("" for none).
Cell = tuple[np.ndarray, str]


def save_sheet(rows: list[list[Cell]], labels: list[str], png: Path, caption: str = "") -> Path:
    """Write the cells as one PNG: a header of column ``labels``, each cell's text on it, ``caption`` below."""
    from PIL import Image, ImageDraw

    sheet = np.concatenate([np.concatenate([img for img, _ in r], axis=1) for r in rows], axis=0)
    header = 16
    w = sheet.shape[1] // len(labels)
    h = sheet.shape[0] // len(rows)
    draw_probe = ImageDraw.Draw(Image.new("RGB", (1, 1)))
    caption_lines = _wrap(caption, lambda t: draw_probe.textlength(t), sheet.shape[1] - 6) if caption else []
    footer = 14 * len(caption_lines) + (4 if caption_lines else 0)
    img = Image.new("RGB", (sheet.shape[1], sheet.shape[0] + header + footer), "white")
    img.paste(Image.fromarray((np.clip(sheet, 0, 1) * 255).astype(np.uint8)), (0, header))
    draw = ImageDraw.Draw(img)
    for i, label in enumerate(labels):
        draw.text((i * w + 3, 2), label, fill="black")
    for r, row in enumerate(rows):
        for c, (_, text) in enumerate(row):
            if text:
                x, y = c * w + 3, header + r * h + 3
                draw.rectangle(draw.textbbox((x, y), text), fill="white")
                draw.text((x, y), text, fill="black")
    for k, line in enumerate(caption_lines):
        draw.text((3, header + sheet.shape[0] + 2 + 14 * k), line, fill="black")
    png.parent.mkdir(parents=True, exist_ok=True)
    img.save(png)
    return png


def _wrap(text: str, width_of: Callable[[str], float], max_width: float) -> list[str]:
    """``text`` in lines no wider than ``max_width`` as ``width_of`` measures them (a longer word stands alone)."""
    lines, line = [], ""
    for word in text.split():
        candidate = f"{line} {word}".strip()
        if line and width_of(candidate) > max_width:
            lines.append(line)
            candidate = word
        line = candidate
    return [*lines, line] if line else lines

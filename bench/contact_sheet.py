"""A PNG contact sheet of a dataset's buffers: one row per frame, one column per buffer."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from gicore.dataset import frame_paths, load_frame, read_meta
from gicore.tonemap import tonemap


def visualize(name: str, arr: np.ndarray) -> np.ndarray:
    """A buffer as an 8-bit RGB image: radiance tone-mapped, normals remapped, depth normalised."""
    if name in ("di", "gt"):
        img = tonemap(arr)
    elif name == "normal":
        img = arr * 0.5 + 0.5
    elif name in ("depth", "mask"):
        hit = arr[..., 0] > 0
        d = arr[..., 0]
        lo, hi = (d[hit].min(), d[hit].max()) if hit.any() else (0.0, 1.0)
        img = np.where(hit, 1.0 - (d - lo) / max(hi - lo, 1e-6), 0.0)[..., None].repeat(3, -1)
    elif name == "position":
        img = np.abs(np.tanh(arr))
    else:
        img = arr
    return (np.clip(img, 0, 1) * 255).astype(np.uint8)


def contact_sheet(dataset: Path, png: Path, split: str = "train", n_frames: int = 4) -> Path:
    meta = read_meta(dataset)
    paths = frame_paths(dataset, split)
    picks = [paths[i] for i in np.linspace(0, len(paths) - 1, min(n_frames, len(paths))).astype(int)]
    rows = [
        np.concatenate([visualize(b, f[b]) for b in meta.buffers], axis=1)
        for f in (load_frame(p, meta.buffers) for p in picks)
    ]
    sheet = np.concatenate(rows, axis=0)
    header = 18
    canvas = Image.new("RGB", (sheet.shape[1], sheet.shape[0] + header), "white")
    canvas.paste(Image.fromarray(sheet), (0, header))
    draw = ImageDraw.Draw(canvas)
    w = sheet.shape[1] // len(meta.buffers)
    for i, b in enumerate(meta.buffers):
        draw.text((i * w + 4, 3), b, fill="black")
    png.parent.mkdir(parents=True, exist_ok=True)
    canvas.save(png)
    return png

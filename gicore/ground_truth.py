"""Scoring a client's composed frames against the path-traced GT at the local camera (docs/architecture.md,
Client loop): the GT render, its scorer and the quality metrics of one frame.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from gicore.camera import Camera
from gicore.metrics import lf_error, psnr, ssim
from gicore.paths import Light, frame_seed
from gicore.render_cache import RenderCache
from gicore.tonemap import tonemap

if TYPE_CHECKING:
    from gicore.render import Renderer

#: A frame's quality columns (:func:`evaluate`), and their values on a frame that is not scored.
QUALITY_COLUMNS = ("ssim", "psnr", "lf_error")
UNSCORED = dict.fromkeys(QUALITY_COLUMNS, "")


def render_gt(
    renderer: Renderer, camera: Camera, light: Light | None, spp: int, seed: int, denoise: bool
) -> np.ndarray:
    """Path-traced GT at ``camera``, OIDN-denoised (albedo/normal guided) when asked."""
    gt = renderer.render_gt(camera, light, spp=spp, seed=seed)
    return renderer.denoise(gt, renderer.render_gbuffers(camera, seed=seed)) if denoise else gt


@dataclass
class GroundTruth:
    """Scores composed frames against the path-traced GT at the local camera, every ``every`` frames.

    ``cache`` (optional, shared between runs of a bench in one process) keeps GT renders by (camera, light,
    spp, denoise, seed, frame); ``store`` (optional) keeps them on disk for other processes (a bench's client
    runs along one path). Neither's renders are part of any stage time.
    """

    renderer: Renderer
    every: int
    spp: int = 64
    denoise: bool = True
    seed: int = 0
    cache: dict | None = None
    store: RenderCache | None = None

    def __post_init__(self) -> None:
        if self.every < 1 or self.spp < 1:
            raise ValueError(f"GT every and spp must be >= 1, got {self.every} and {self.spp}")

    def reference(self, frame: int, camera: Camera, light: Light) -> np.ndarray:
        key = ("gt", camera, tuple(light), self.spp, self.denoise, self.seed, frame)
        if self.cache is not None and key in self.cache:
            return self.cache[key]

        def render() -> np.ndarray:
            return render_gt(self.renderer, camera, light, self.spp, frame_seed(self.seed, "gt", frame), self.denoise)

        gt = self.store.fetch(key, lambda: {"gt": render()})["gt"] if self.store is not None else render()
        if self.cache is not None:
            self.cache[key] = gt
        return gt

    def score(self, frame: int, camera: Camera, light: Light, image: np.ndarray) -> dict[str, float | str]:
        """SSIM, PSNR and low-frequency error (tone-mapped; PSNR may be inf) on scored frames, ``""`` on the others."""
        if frame % self.every:
            return dict(UNSCORED)
        return evaluate(image, self.reference(frame, camera, light))


def evaluate(image: np.ndarray, gt: np.ndarray) -> dict[str, float]:
    """SSIM, PSNR and low-frequency error (:func:`gicore.metrics.lf_error`) of a composed frame against the
    GT, both tone-mapped (PSNR may be inf)."""
    a, b = tonemap(image), tonemap(gt)
    return {"ssim": ssim(a, b), "psnr": psnr(a, b), "lf_error": lf_error(a, b)}

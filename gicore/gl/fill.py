"""The push-pull hole filling (:func:`gicore.fill.push_pull`) as GL passes (``pull.frag``, ``push.frag``): the
pixel-level warp fills its holes with it and the structure-aware warp's fallback level is made with it, on the
desktop as on the Web3D page (``web3d/static/js/fill.js``)."""

from __future__ import annotations

from typing import Any

from gicore.gl.passes import Pass, Target
from gicore.gl.sources import glsl


def pyramid_sizes(width: int, height: int) -> list[tuple[int, int]]:
    """The push-pull's level sizes, finest first: halved (rounded up) until one pixel is left."""
    sizes = [(width, height)]
    while max(sizes[-1]) > 1:
        w, h = sizes[-1]
        sizes.append((-(-w // 2), -(-h // 2)))
    return sizes


class PushPull:
    """The pull and push levels of a ``width`` x ``height`` image in ``ctx``: draw the finest level into
    :attr:`level0` (colour premultiplied by its weight in [0, 1], the weight in alpha), then :meth:`run`."""

    def __init__(self, ctx: Any, width: int, height: int):
        self.size = (width, height)
        self._pull, self._push = Pass(ctx, glsl("pull.frag")), Pass(ctx, glsl("push.frag"))
        sizes = pyramid_sizes(width, height)
        self._pulled = [Target.make(ctx, w, h, 4) for w, h in sizes]
        self._pushed = [Target.make(ctx, w, h, 4) for w, h in sizes[:-1]]

    @property
    def level0(self) -> Target:
        return self._pulled[0]

    def run(self, mask: Any | None = None) -> Target:
        """The filled image (colour; alpha: the finest level's weight); with ``mask``, a texture whose alpha says
        where the frame sees a surface, the pixels off it are background (0, alpha 1)."""
        for finer, coarser in zip(self._pulled, self._pulled[1:]):
            self._pull.draw(coarser, {"u_finer": finer.texture})
        top = len(self._pushed) - 1
        for level in range(top, -1, -1):
            coarser = self._pulled[-1] if level == top else self._pushed[level + 1]
            inputs = {"u_level": self._pulled[level].texture, "u_coarser": coarser.texture}
            flags = {"u_top": level == top, "u_masked": level == 0 and mask is not None}
            self._push.draw(self._pushed[level], inputs | {"u_mask": mask or coarser.texture}, flags)
        return self._pushed[0] if self._pushed else self._pulled[0]

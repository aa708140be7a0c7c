"""What several benches share, so that no bench imports another (pyproject.toml, the protected contract):
the warp methods they compare and a stated target.

The warps are wired here, in ``bench``, because cross-system ablations (GIGAN maps with cloud baking's
pixel-level warp) may not be assembled inside either system (docs/architecture.md, Import contracts).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from gicore.gi_map import LAYERS
from gicore.loop import Warp

# --- the warp methods ----------------------------------------------------------------------------------------

#: Plot and CSV names of the warp methods the benches compare: GIGAN's structure-aware warp, cloud
#: baking's pixel-level warp, and none (the map pasted as is).
WARP_LABELS = {"structure": "structure-aware", "pixel": "pixel-level", "none": "no warping"}
WARPS = tuple(WARP_LABELS)


def make_warp(method: str, renderer, composition: str = "blend") -> Warp:
    """The :class:`gicore.loop.Warp` ``method`` (:data:`WARPS`) for ``composition``."""
    if method == "pixel":
        from baseline_cloudbaking.warp import PixelWarp

        return PixelWarp(LAYERS[composition])
    from gigan_local.client import make_warp as gigan_warp

    return gigan_warp(method, renderer, composition)


# --- stated targets ------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Target:
    """One of the server's stated targets (``bench service``, ``bench load``): ``metric``'s ``stat`` compared
    with ``bound`` (``at_most`` or not)."""

    metric: str
    stat: str
    bound: float
    unit: str
    at_most: bool
    label: str
    #: Extra config keys that select the row (e.g. the hit_server part).
    where: tuple[tuple[str, str], ...] = ()

    def met(self, value: float) -> bool:
        return value <= self.bound if self.at_most else value >= self.bound

    def record(self, add: Callable[..., None], measured: float | None, **config: Any) -> None:
        """Its ``stat = target_met`` row through ``add`` (a ``Results.add`` with system and scene bound): 1 when
        ``measured`` meets it, 0 when it does not or was not measured."""
        met = measured is not None and not math.isnan(measured) and self.met(measured)
        add(metric=self.metric, value=int(met), unit="bool", stat="target_met", target=self.label, bound=self.bound,
            bound_unit=self.unit, measured=measured, **config)  # fmt: skip

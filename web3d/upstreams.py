"""Where the page's GI-map requests go: a cloud-baking server per store state, each seen through a network
profile (a ``network-sim proxy`` in front of it, or the server itself).

A :class:`Cloud` names its profiles and stores (the first of each is the page's default) and gives the base
URL for a pair. :class:`Fixed` holds servers the user runs (``gigan-web --server URL``: store ``given``,
profile ``direct``; none: the cloud side is off); :class:`web3d.children.ChildCloud` starts its own.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import httpx

#: Seconds a status probe waits for a server the user runs.
PROBE_TIMEOUT_S = 2.0


class Unavailable(Exception):
    """No server answers for that profile and store (answered 503, with this message)."""


class Cloud(Protocol):
    """The cloud side as the page's server sees it."""

    @property
    def profiles(self) -> tuple[str, ...]: ...

    @property
    def stores(self) -> tuple[str, ...]: ...

    def upstream(self, profile: str, store: str) -> str:
        """The base URL for ``profile`` and ``store`` (both among :attr:`profiles`, :attr:`stores`); it may start
        processes first (blocking); :class:`Unavailable` when none answers."""
        ...

    def status(self) -> dict[str, dict[str, str]]:
        """``{"profiles": {name: "up"|"down"}, "stores": {name: "up"|"down"|"idle"}}`` (idle: started on its
        first request)."""
        ...

    def __enter__(self) -> Cloud:
        """Start what the cloud side runs before the page is served."""
        ...

    def __exit__(self, *exc: object) -> None:
        """Stop everything it started."""
        ...


@dataclass(frozen=True)
class Fixed:
    """Servers the user runs: the base URL of each (store, profile) pair; none: the cloud side is off."""

    urls: dict[tuple[str, str], str] = field(default_factory=dict)

    @classmethod
    def direct(cls, url: str) -> Fixed:
        """One server the page talks to as it is (``--server URL``: a server or a proxy in front of it)."""
        return cls({("given", "direct"): url.rstrip("/")})

    @property
    def profiles(self) -> tuple[str, ...]:
        return tuple(dict.fromkeys(profile for _, profile in self.urls))

    @property
    def stores(self) -> tuple[str, ...]:
        return tuple(dict.fromkeys(store for store, _ in self.urls))

    def upstream(self, profile: str, store: str) -> str:
        try:
            return self.urls[store, profile]
        except KeyError:
            raise Unavailable(f"no server for profile {profile} and store {store}") from None

    def status(self) -> dict[str, dict[str, str]]:
        up = {pair: _answers(url) for pair, url in self.urls.items()}
        return {
            "profiles": {p: "up" if any(ok for (_, q), ok in up.items() if q == p) else "down" for p in self.profiles},
            "stores": {s: "up" if any(ok for (t, _), ok in up.items() if t == s) else "down" for s in self.stores},
        }

    def __enter__(self) -> Fixed:
        return self  # the user runs these servers

    def __exit__(self, *exc: object) -> None:
        pass


def _answers(url: str) -> bool:
    """Whether the cloud-baking server at ``url`` answers its health check."""
    try:
        return httpx.get(f"{url}/v1/health", timeout=PROBE_TIMEOUT_S).status_code == 200
    except httpx.HTTPError:
        return False


#: The cloud side off: no profile, no store; ``/v1/gimap`` answers 503.
OFF = Fixed()

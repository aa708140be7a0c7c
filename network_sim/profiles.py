"""Named link profiles, each number with its source (``network-sim profiles`` lists them).

``delay_ms`` is one-way, so a source's round-trip time is split evenly over the two directions.
No profile adds jitter or loss: none of the sources gives a number for them (add ``--jitter-ms`` /
``--loss`` on top of a profile). Explicit proxy flags override a profile's values.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any

from gicore.error_policy import UserError
from gicore.option_groups import shared
from network_sim.link import DirectionConfig, LinkConfig
from network_sim.trace import Trace
from network_sim.tracegen import MODELS, shipped_path


@dataclass(frozen=True)
class Profile:
    """A named pair of direction settings and where their numbers come from."""

    name: str
    #: Client -> server direction.
    up: DirectionConfig
    #: Server -> client direction.
    down: DirectionConfig
    #: The source of every number, in one sentence.
    source: str

    def link(self, *, seed: int = 0) -> LinkConfig:
        return LinkConfig(up=self.up, down=self.down, seed=seed)


def _symmetric(
    name: str, rtt_ms: float, rate_mbit: float | None, source: str, rate_up_mbit: float | None = None
) -> Profile:
    up = DirectionConfig(delay_ms=rtt_ms / 2, rate_mbit=rate_mbit if rate_up_mbit is None else rate_up_mbit)
    return Profile(name, up, DirectionConfig(delay_ms=rtt_ms / 2, rate_mbit=rate_mbit), source)


def _traced(name: str, rtt_ms: float, source: str) -> Profile:
    def direction(which: str) -> DirectionConfig:
        model = MODELS[f"{name}.{which}"]
        return DirectionConfig(delay_ms=rtt_ms / 2, trace=Trace.load(shipped_path(model.file)))

    return Profile(name, direction("up"), direction("down"), source)


_OUTATIME = (
    "Outatime (Lee et al., MobiSys 2015, §1): players notice 60 ms, are aggravated past 100 ms, Outatime masks up to "
    "120 ms and its technical report up to 250 ms of RTT; delay only, rate unlimited so the sweep varies RTT alone"
)


@functools.cache
def profiles() -> dict[str, Profile]:
    """Every profile by name (built on first use: the LTE ones parse their shipped traces)."""
    wifi_up = 15.0  # Firefox DevTools "Wi-Fi": 30 Mbit/s down, 15 Mbit/s up
    profiles = [
        Profile(
            "loopback",
            DirectionConfig(),
            DirectionConfig(),
            "no shaping: the proxy alone (its overhead is measured by network-sim selftest)",
        ),
        _symmetric(
            "lan",
            0.5,
            1000.0,
            "Gigabit Ethernet line rate (IEEE 802.3ab 1000BASE-T); 0.5 ms RTT is an assumption "
            "(no measured source; the order of a ping across one switch)",
        ),
        _symmetric(
            "wifi",
            2.0,
            30.0,
            "Firefox DevTools throttling preset 'Wi-Fi': 30 Mbit/s down, 15 Mbit/s up, 2 ms latency (taken as the RTT)",
            rate_up_mbit=wifi_up,
        ),
        _symmetric(
            "wan",
            130.0,
            5.0,
            "GamingAnywhere (Huang et al., MMSys 2013, §5.1): the path to OnLive's server had "
            "'around 130 ms' delay (taken as the RTT) and carried OnLive's recommended 5 Mbit/s with loss < 1e-6",
        ),
        _traced(
            "lte",
            70.0,
            "traces generated to match Mahimahi's Verizon-LTE-short (mean 5.03 down / 5.95 up Mbit/s, "
            "network_sim.tracegen); 70 ms RTT from WebPageTest's 'LTE (12 Mbps, 70ms RTT)' connectivity profile",
        ),
        _traced(
            "lte-fast",
            70.0,
            "traces generated to match Mahimahi's TMobile-LTE-short (mean 16.70 down / 13.32 up "
            "Mbit/s, network_sim.tracegen); 70 ms RTT from WebPageTest's LTE connectivity profile",
        ),
        _symmetric(
            "3g",
            300.0,
            0.7,
            "Lighthouse's 'mobileRegular3G' throttling (core/config/constants.js): rttMs 300, throughputKbps 700",
        ),
    ]
    profiles += [_symmetric(f"rtt{rtt}", float(rtt), None, _OUTATIME) for rtt in (60, 100, 120, 250)]
    return {p.name: p for p in profiles}


def get(name: str) -> Profile:
    """The profile called ``name``, or a :class:`UserError` listing the known ones."""
    check_profile("--profile", name)
    return profiles()[name]


def check_profile(option: str, name: str) -> None:
    """A :class:`UserError` naming ``option`` unless ``name`` is a profile."""
    known = profiles()
    if name not in known:
        raise UserError(
            f"{option} {name!r} is not a known profile", f"use one of {', '.join(known)} (see network-sim profiles)"
        )


PROFILE_HELP = "Network profile (see 'network-sim profiles')"
PROFILES_HELP = "Network profiles (see 'network-sim profiles')"


def profile_field(default: str | None = "lan", *, note: str = "") -> Any:
    """``--profile``, one named link (a shared option, :mod:`gicore.option_groups`), checked to be known."""
    return shared("profile", default, PROFILE_HELP, note, check=check_profile)


def profiles_field(default: tuple[str, ...] = ("lan", "wifi", "lte", "wan"), *, note: str = "") -> Any:
    """``--profiles``, named links, each checked to be known."""
    return shared("profiles", default, PROFILES_HELP, note, check=check_profile)

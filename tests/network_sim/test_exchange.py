"""One request and its response on a modelled link (network_sim.exchange): the crossover against closed forms and
a profile's total."""

from __future__ import annotations

import pytest

from network_sim.exchange import CloudCost, sweep_link


def test_crossover_matches_the_closed_form() -> None:
    """Unlimited rate: the network costs exactly the RTT, so the local alternative wins beyond (its total - the
    service's local part); at 5 Mbit/s the response's serialization (bytes * 8 / rate) is added to the service."""
    cost = CloudCost(local_ms=10.0, server_ms=5.0, bytes_up=500, bytes_down=100_000)
    assert cost.network_ms(sweep_link(80.0, None)) == pytest.approx(80.0, abs=1e-6)
    assert cost.crossover_rtt_ms(40.0, None) == pytest.approx(30.0, abs=0.1)
    assert cost.crossover_rtt_ms(5.0, None) == 0.0  # the local alternative is faster at any RTT
    serialization_ms = (500 + 100_000) * 8 / 5e6 * 1e3
    assert cost.network_ms(sweep_link(80.0, 5.0)) == pytest.approx(80.0 + serialization_ms, abs=0.01)
    assert cost.crossover_rtt_ms(400.0, 5.0) == pytest.approx(400.0 - 10.0 - serialization_ms, abs=0.1)


def test_link_model_of_a_profile() -> None:
    """The wan profile: 130 ms RTT and 5 Mbit/s each way."""
    from network_sim.profiles import get

    cost = CloudCost(local_ms=0.0, server_ms=50.0, bytes_up=1000, bytes_down=62_500)
    assert cost.total_ms(get("wan").link(), starts=5) == pytest.approx(130.0 + (1000 + 62_500) * 8 / 5e6 * 1e3, abs=0.1)


def test_medians_of_measured_requests() -> None:
    samples = {"total": [30.0, 50.0, 40.0], "transmission": [10.0, 20.0, 15.0], "server": [5.0, 7.0, 6.0],
               "bytes_up": [500, 500, 600], "bytes_down": [1000, 3000, 2000]}  # fmt: skip
    assert CloudCost.of(samples) == CloudCost(local_ms=25.0, server_ms=6.0, bytes_up=500, bytes_down=2000)

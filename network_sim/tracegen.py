"""Seeded LTE-like capacity traces (Mahimahi format), generated here instead of downloaded.

The model is a Markov-modulated Poisson process: a hidden log-rate follows a Gaussian AR(1) chain
updated every ``STEP_S``, an on/off Markov chain adds outages (no capacity), and within each step
delivery opportunities arrive as a Poisson process at the current rate (1500 bytes each). The rate path
is scaled so the trace's mean capacity is the target exactly (up to the Poisson draw).

The parameters of each shipped trace were fitted (by grid search, comparing :func:`trace_stats`) to the
statistics of one of Mahimahi's recorded cellular traces (``traces/`` of github.com/ravinet/mahimahi at
commit ae477d4, recorded with Sprout's Saturator, Winstein et al., NSDI 2013): mean capacity, the
coefficient of variation and lag-1 autocorrelation of the capacity in 100 ms bins, and the share of
100 ms bins with no capacity. The recorded traces are not copied or shipped; ``network-sim traces
--out DIR`` regenerates the shipped files bit for bit (a test checks it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from network_sim.trace import OPPORTUNITY_BYTES, Trace

#: Update interval of the hidden rate and outage chains.
STEP_S = 0.02
#: Bin width of the statistics the models were fitted on.
BIN_S = 0.1


@dataclass(frozen=True)
class TraceModel:
    """Parameters of one synthetic trace and the recorded statistics it was fitted to."""

    #: File name inside ``network_sim/traces``.
    file: str
    #: Mean capacity, Mbit/s (the recorded trace's mean).
    mean_mbit: float
    #: Standard deviation of the log-rate (marginal of the AR(1) chain).
    log_sigma: float
    #: Correlation time of the log-rate, seconds (AR(1) coefficient exp(-STEP_S / tau)).
    tau_s: float
    #: Probability per step of entering an outage, and mean outage length in seconds.
    outage_rate: float
    outage_s: float
    #: Length of the trace (its period), seconds.
    seconds: int
    seed: int
    #: The recorded trace and its statistics (mean Mbit/s, CV and lag-1 autocorrelation of 100 ms bins,
    #: share of empty 100 ms bins), computed with :func:`trace_stats` on Mahimahi's file.
    source: str


#: The shipped traces. ``lte``: Verizon LTE (the low end of Mahimahi's LTE means); ``lte-fast``: T-Mobile
#: LTE (the high end). Recorded statistics in ``source``; the fitted model's own are checked by a test.
MODELS: dict[str, TraceModel] = {
    "lte.down": TraceModel(
        "lte.down.txt",
        5.03,
        0.6,
        1.3,
        0.003,
        0.2,
        60,
        1,
        "Mahimahi Verizon-LTE-short.down: mean 5.03 Mbit/s, cv100 0.71, ac100 0.87, empty100 0.016",
    ),
    "lte.up": TraceModel(
        "lte.up.txt",
        5.95,
        0.55,
        0.9,
        0.0015,
        0.4,
        60,
        2,
        "Mahimahi Verizon-LTE-short.up: mean 5.95 Mbit/s, cv100 0.60, ac100 0.87, empty100 0.021",
    ),
    "lte-fast.down": TraceModel(
        "lte-fast.down.txt",
        16.70,
        0.6,
        0.8,
        0.008,
        0.15,
        60,
        3,
        "Mahimahi TMobile-LTE-short.down: mean 16.70 Mbit/s, cv100 0.69, ac100 0.84, empty100 0.036",
    ),
    "lte-fast.up": TraceModel(
        "lte-fast.up.txt",
        13.32,
        0.65,
        2.0,
        0.003,
        0.1,
        60,
        4,
        "Mahimahi TMobile-LTE-short.up: mean 13.32 Mbit/s, cv100 0.64, ac100 0.93, empty100 0.005",
    ),
}


def generate(model: TraceModel) -> list[int]:
    """Millisecond timestamps of the trace (non-decreasing; the last one is the period)."""
    # numpy is imported by the two functions that use it: every proxy imports this module for the shipped traces'
    # names and paths, and a proxy has no other use for numpy (0.1 s of its start).
    import numpy as np

    rng = np.random.default_rng(model.seed)
    steps = round(model.seconds / STEP_S)
    phi = math.exp(-STEP_S / model.tau_s)
    shocks = rng.standard_normal(steps) * math.sqrt(1.0 - phi * phi)
    log_rate = np.empty(steps)
    level = rng.standard_normal()
    for i in range(steps):
        log_rate[i] = level
        level = phi * level + shocks[i]
    # outages: enter with probability outage_rate per step, leave with probability STEP_S / outage_s
    leave = min(1.0, STEP_S / model.outage_s)
    on = np.ones(steps, dtype=bool)
    u = rng.random(steps)
    state = True
    for i in range(steps):
        state = (u[i] >= model.outage_rate) if state else (u[i] < leave)
        on[i] = state
    rate = np.exp(model.log_sigma * log_rate) * on
    rate *= model.mean_mbit / rate.mean()  # Mbit/s per step, mean exactly the target
    ms_per_step = round(STEP_S * 1000)
    per_ms = np.repeat(rate * 1e6 / 8 / OPPORTUNITY_BYTES / 1000.0, ms_per_step)  # expected opportunities per ms
    counts = rng.poisson(per_ms)
    stamps = np.repeat(np.arange(1, counts.size + 1), counts).tolist()
    if not stamps or stamps[-1] != model.seconds * 1000:
        stamps.append(model.seconds * 1000)  # the last timestamp is the period
    return stamps


def trace_stats(trace: Trace) -> dict[str, float]:
    """Mean capacity (Mbit/s) and the 100 ms-bin statistics the models are fitted on."""
    import numpy as np

    bin_ms = round(BIN_S * 1000)
    bins = np.bincount(np.minimum(np.asarray(trace.times_ms) // bin_ms, trace.period_ms // bin_ms - 1))
    mbit = bins * OPPORTUNITY_BYTES * 8 / BIN_S / 1e6
    return {
        "mean_mbit": trace.mean_mbit,
        "cv100": float(mbit.std() / mbit.mean()),
        "ac100": float(np.corrcoef(mbit[:-1], mbit[1:])[0, 1]),
        "empty100": float(np.mean(bins == 0)),
    }


def shipped_path(file: str) -> Path:
    """Path of a trace file shipped inside the package."""
    return Path(str(resources.files("network_sim") / "traces" / file))


def write_traces(out: Path) -> list[Path]:
    """Generate every shipped trace into ``out``; returns the files written."""
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for model in MODELS.values():
        path = out / model.file
        path.write_text("".join(f"{ms}\n" for ms in generate(model)))
        written.append(path)
    return written

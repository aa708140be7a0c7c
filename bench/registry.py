"""Every bench, registered once: ``bench --help`` lists their subcommands in this order, and ``bench report``
shows the dashboard section and README block each declares (placed by their own ``order``).

To add a bench, write its module (:mod:`bench.runner` says how), import it here and add its ``BENCH`` to
:data:`BENCHES`. Benches import no bench (pyproject.toml, the protected contract): one that runs others
(run-default, model-card, pareto) is made here, from theirs, by its module's ``bench(...)``. ``bench report``
is not in the list: it reads the list, so :mod:`bench.cli` adds it after the others.
"""

from __future__ import annotations

from bench import (
    convergence,
    fov,
    frequency,
    inference_bench,
    latency,
    load,
    model_card,
    pareto,
    prefetch,
    quality,
    render_bench,
    run_default,
    scaling,
    server_bench,
    stability,
    storage,
    training,
    variant_bench,
    viewer_bench,
    warp_bench,
)
from bench.runner import Bench, Block, External
from network_sim import selftest, selftest_report

#: Every ``bench`` subcommand but ``report``, in the order ``bench --help`` lists them.
BENCHES: tuple[Bench, ...] = (
    run_default.bench(latency.BENCH, storage.BENCH),
    convergence.BENCH,
    render_bench.BENCH,
    inference_bench.BENCH,
    quality.BENCH,
    training.BENCH,
    model_card.bench(quality.BENCH),
    warp_bench.BENCH,
    frequency.BENCH,
    fov.BENCH,
    latency.BENCH,
    prefetch.BENCH,
    storage.BENCH,
    server_bench.BENCH,
    variant_bench.BENCH,
    load.BENCH,
    stability.BENCH,
    scaling.BENCH,
    pareto.bench(frequency.BENCH),
    viewer_bench.BENCH,
)

#: The CSVs of other programs that ``bench report`` shows as it shows a bench's.
EXTERNALS: tuple[External, ...] = (
    External(
        selftest.BENCH,
        readme=Block("Network simulator", 90, make="network-sim selftest --out {out}/netself"),
        parts=selftest_report.PARTS,
    ),
)


def reported() -> tuple[Bench | External, ...]:
    """Everything ``bench report`` shows: the benches of :data:`BENCHES` and :data:`EXTERNALS`, as they are when
    it runs."""
    return (*BENCHES, *EXTERNALS)

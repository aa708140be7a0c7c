"""The bench registry: every bench once, each place in the report its own (a new bench's one registration line:
tests/bench/test_bench_extension.py)."""

from __future__ import annotations

from bench import cli, registry, report


def test_every_bench_is_registered_once_and_each_place_in_the_report_is_its_own() -> None:
    names = [b.name for b in cli.BENCHES]
    assert names[-1] == "report" and len(set(names)) == len(names)
    assert cli.BENCHES == (*registry.BENCHES, report.BENCH)
    sections = [s.dashboard for s in registry.reported() if s.dashboard is not None]
    blocks = [s.readme for s in registry.reported() if s.readme is not None]
    for places in (sections, blocks):
        assert len({p.order for p in places}) == len(places) and len({p.title for p in places}) == len(places)
    assert len({s.key for s in sections}) == len(sections)

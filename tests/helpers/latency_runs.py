"""``bench latency`` with its processes stood in for, for the tests that check what each client run, the prefill
and the recorder are told (:func:`stand_in`)."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import pytest

from bench import latency


@dataclass
class Told:
    """What bench latency told its stand-ins: each client's argv, each prefill's config, the recorder's config
    and common columns."""

    argvs: list[list[str]] = field(default_factory=list)
    asked: list[Any] = field(default_factory=list)
    recorded: dict[str, Any] = field(default_factory=dict)


def stand_in(monkeypatch: pytest.MonkeyPatch) -> Told:
    """Servers, proxies, clients and the recorder of :mod:`bench.latency` replaced by stand-ins that note what
    they are told (one renderer: mitsuba)."""
    told = Told()

    @contextmanager
    def process(*args: Any) -> Iterator[str]:
        yield "http://127.0.0.1:9"

    monkeypatch.setattr(latency, "available_renderers", lambda asked: (("mitsuba",), {}))
    monkeypatch.setattr(latency, "pinned_server", process)
    monkeypatch.setattr(latency, "pinned_proxy", process)
    asked = lambda url, scene, cfg, seed, **kw: told.asked.append(cfg) or {"misses": cfg.frames}  # noqa: E731
    monkeypatch.setattr(latency, "request_path_maps", asked)
    monkeypatch.setattr(latency, "run_client", lambda plan, argv, out, timeout: told.argvs.append(argv) or out)
    monkeypatch.setattr(latency, "_ran_on", lambda folder, renderer: folder)
    monkeypatch.setattr(
        latency, "record", lambda res, name, cfg, runs, common: told.recorded.update(cfg=cfg, common=common)
    )
    return told

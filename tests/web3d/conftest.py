"""What gigan-web's server logs during a test: the ``tracebacks`` fixture fails a test whose requests made it log
an exception."""

from __future__ import annotations

import logging
from collections.abc import Iterator

import pytest


class Collect(logging.Handler):
    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.records: list[logging.LogRecord] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append(record)


@pytest.fixture
def tracebacks() -> Iterator[list[logging.LogRecord]]:
    """What the server logs during a test (uvicorn's loggers, which do not propagate to the root); none may
    carry an exception."""
    collect = Collect()
    logger = logging.getLogger("uvicorn")
    logger.addHandler(collect)
    try:
        yield collect.records
    finally:
        logger.removeHandler(collect)
    failed = [r.getMessage() for r in collect.records if r.exc_info]
    assert not failed, failed

"""The one config mechanism: a dataclass per component, read back from plain JSON by :func:`strict_from_dict`.

Configs are written as ``asdict(cfg)`` and read with ``strict_from_dict``, which refuses unknown and
missing fields by name instead of ignoring them or failing with a ``TypeError``, so a config file made
by another version, or edited by hand, is rejected with a message that says which field is wrong. This
module imports nothing heavy: reading a config never loads torch or Mitsuba.
"""

from __future__ import annotations

from dataclasses import MISSING, fields
from typing import Any, TypeVar

T = TypeVar("T")


def strict_from_dict(cls: type[T], d: Any, what: str) -> T:
    """Build config dataclass ``cls`` from plain JSON data; ValueError names unknown or missing fields.

    ``what`` names the config in messages (e.g. ``"training"``). The dataclass's own ``__post_init__``
    checks the values.
    """
    if not isinstance(d, dict):
        raise ValueError(f"the {what} config must be a JSON object, got {type(d).__name__}")
    declared = fields(cls)  # type: ignore[arg-type]
    known = {f.name for f in declared}
    unknown = sorted(set(d) - known)
    if unknown:
        raise ValueError(f"unknown {what} config field(s) {unknown}; known: {sorted(known)}")
    required = {f.name for f in declared if f.default is MISSING and f.default_factory is MISSING and f.init}
    missing = sorted(required - set(d))
    if missing:
        raise ValueError(f"the {what} config lacks field(s) {missing}")
    return cls(**d)

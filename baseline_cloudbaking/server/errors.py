"""The server's error answers, one shape for all: ``{"detail": [{"loc": [...], "msg": ..., "type": ...}]}``
with a one-line ``msg`` (FastAPI's 422 shape without the echoed input), and how the OpenAPI document
states them."""

from __future__ import annotations

import logging
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse

from baseline_cloudbaking.server.service import FieldError, QueueFull
from baseline_cloudbaking.store import StoreUnwritable

log = logging.getLogger("baseline_cloudbaking.server")

_DETAIL = {
    "application/json": {
        "schema": {
            "type": "object",
            "properties": {
                "detail": {
                    "type": "array",
                    "items": {
                        "type": "object",
                        "properties": {
                            "loc": {"type": "array", "items": {"type": ["string", "integer"]}},
                            "msg": {"type": "string"},
                            "type": {"type": "string"},
                        },
                        "required": ["loc", "msg", "type"],
                    },
                }
            },
            "required": ["detail"],
        }
    }
}
_RETRY = {"Retry-After": {"description": "seconds to wait before trying again", "schema": {"type": "integer"}}}

#: Responses every route may give besides its own (the OpenAPI document lists them).
ERROR_RESPONSES: dict[int | str, dict[str, Any]] = {
    400: {"description": "the HTTP request itself is malformed (answered by the HTTP layer, as text)"},
    408: {"description": "the request body did not arrive within body_timeout_s", "content": _DETAIL},
    413: {"description": "request body too large (max_body_bytes)", "content": _DETAIL},
    431: {"description": "request head too large (max_header_bytes); the connection is closed", "content": _DETAIL},
    422: {"description": "a field is invalid; detail[].loc names it", "content": _DETAIL},
    503: {
        "description": "overloaded (the miss queue or the connection limit is full) or the GI tree cannot be "
        "written now (read-only, failing storage); try again after Retry-After seconds",
        "content": _DETAIL,
        "headers": _RETRY,
    },
    507: {"description": "no space left to store the baked map (disk, quota or index full)", "content": _DETAIL},
}


def error(status: int, loc: list[str], msg: str, kind: str, headers: dict[str, str] | None = None) -> JSONResponse:
    return JSONResponse({"detail": [{"loc": loc, "msg": msg, "type": kind}]}, status_code=status, headers=headers)


def queue_full(exc: QueueFull) -> JSONResponse:
    return error(503, ["miss_queue"], str(exc), "overloaded", {"Retry-After": str(exc.retry_after_s)})


def install(app: FastAPI) -> None:
    """The exception handlers that answer in this shape."""

    @app.exception_handler(RequestValidationError)
    async def invalid_request(_: Request, exc: RequestValidationError) -> JSONResponse:
        # FastAPI's default echoes each bad input, which cannot be JSON when it is NaN or Infinity
        detail = [{"loc": list(e["loc"]), "msg": e["msg"], "type": e["type"]} for e in exc.errors()]
        return JSONResponse({"detail": detail}, status_code=422)

    @app.exception_handler(FieldError)
    async def field_error(_: Request, exc: FieldError) -> JSONResponse:
        return error(exc.status, ["body", exc.field], exc.message, "value_error")

    @app.exception_handler(QueueFull)
    async def on_queue_full(_: Request, exc: QueueFull) -> JSONResponse:
        return queue_full(exc)

    @app.exception_handler(StoreUnwritable)
    async def store_unwritable(_: Request, exc: StoreUnwritable) -> JSONResponse:
        log.error("%s", exc)  # throttled: a full disk fails every miss
        if exc.full:
            return error(507, ["store"], exc.what, "store_full")
        return error(503, ["store"], exc.what, "store_unwritable", {"Retry-After": "10"})

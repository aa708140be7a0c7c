"""The server's error answers, one shape for all: ``{"detail": [{"loc": [...], "msg": ..., "type": ...}]}``
with a one-line ``msg`` (FastAPI's 422 shape without the echoed input), and how the OpenAPI document
states them. No answer names an absolute path (:func:`redact`): a client learns the names of files it
may need (a scene's spec file, a store file), never where the server keeps them."""

from __future__ import annotations

import logging
import re
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException

from baseline_cloudbaking.server.service import FieldError, QueueFull, ServerStopping
from baseline_cloudbaking.server.settings import Settings
from baseline_cloudbaking.store_errors import StoreClosed, StoreUnwritable

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
    400: {
        "description": "the HTTP request itself is malformed (answered by the HTTP layer, as text), or its body "
        "cannot be parsed"
    },
    408: {"description": "the request body did not arrive within body_timeout_s", "content": _DETAIL},
    413: {"description": "request body too large (max_body_bytes)", "content": _DETAIL},
    431: {"description": "request head too large (max_header_bytes); the connection is closed", "content": _DETAIL},
    422: {"description": "a field is invalid; detail[].loc names it", "content": _DETAIL},
    503: {
        "description": "overloaded (the miss queue or the connection limit is full), the GI tree cannot be "
        "written now (read-only, failing storage), or the server is stopping; try again after Retry-After seconds",
        "content": _DETAIL,
        "headers": _RETRY,
    },
    507: {"description": "no space left to store the baked map (disk, quota or index full)", "content": _DETAIL},
}


#: An absolute POSIX path in a message: from a slash not inside a word, URL or relative path, to a delimiter.
_ABSOLUTE = re.compile(r"(?<![\w.~:/-])/[^\s'\"`,;()\[\]{}<>]+")


def redact(text: str, roots: Iterable[Path] = ()) -> str:
    """``text`` with each absolute path made relative to the folder of ``roots`` that holds it (a root itself
    becomes its name), and any other absolute path on this machine cut to its last component."""
    for root in sorted({str(r) for r in roots if r.is_absolute()}, key=len, reverse=True):
        text = text.replace(root + "/", "").replace(root, Path(root).name)

    def last(match: re.Match[str]) -> str:
        path = Path(match.group(0))
        return path.name if len(path.parts) > 1 and Path(*path.parts[:2]).exists() else match.group(0)

    return _ABSOLUTE.sub(last, text)


def public_roots(settings: Settings) -> list[Path]:
    """The folders whose files answers may name (relative to them): the GI tree's and the scenes', as given
    and resolved."""
    folders = [f for f in (settings.store, settings.scenes_dir) if f is not None]
    return [f.absolute() for f in folders] + [f.resolve() for f in folders]


def public(request: Request, text: str) -> str:
    """``text`` as an answer to ``request`` may state it (:func:`redact`)."""
    return redact(text, public_roots(request.app.state.settings))


def error(status: int, loc: list[str], msg: str, kind: str, headers: dict[str, str] | None = None) -> JSONResponse:
    return JSONResponse({"detail": [{"loc": loc, "msg": msg, "type": kind}]}, status_code=status, headers=headers)


def queue_full(exc: QueueFull) -> JSONResponse:
    return error(503, ["miss_queue"], str(exc), "overloaded", {"Retry-After": str(exc.retry_after_s)})


def stopping(exc: ServerStopping) -> JSONResponse:
    """503: the server is stopping (the connection closes with the answer)."""
    headers = {"Retry-After": str(exc.retry_after_s), "Connection": "close"}
    return error(503, ["server"], str(exc), "stopping", headers)


def install(app: FastAPI) -> None:
    """The exception handlers that answer in this shape."""

    @app.exception_handler(HTTPException)
    async def http_error(_: Request, exc: HTTPException) -> JSONResponse:
        # FastAPI's own refusals (a body it cannot parse, e.g. nested too deep; an unknown path or method)
        loc = {400: ["body"], 404: ["path"], 405: ["method"]}.get(exc.status_code, ["request"])
        return error(exc.status_code, loc, str(exc.detail), "http_error", exc.headers)

    @app.exception_handler(RequestValidationError)
    async def invalid_request(request: Request, exc: RequestValidationError) -> JSONResponse:
        # FastAPI's default echoes each bad input, which cannot be JSON when it is NaN or Infinity
        detail = [{"loc": list(e["loc"]), "msg": public(request, e["msg"]), "type": e["type"]} for e in exc.errors()]
        return JSONResponse({"detail": detail}, status_code=422)

    @app.exception_handler(FieldError)
    async def field_error(request: Request, exc: FieldError) -> JSONResponse:
        return error(exc.status, ["body", exc.field], public(request, exc.message), "value_error")

    @app.exception_handler(StoreClosed)
    async def on_store_closed(_: Request, exc: StoreClosed) -> JSONResponse:
        return stopping(ServerStopping())  # the tree is closed only once the server stops

    @app.exception_handler(QueueFull)
    async def on_queue_full(_: Request, exc: QueueFull) -> JSONResponse:
        return queue_full(exc)

    @app.exception_handler(StoreUnwritable)
    async def store_unwritable(request: Request, exc: StoreUnwritable) -> JSONResponse:
        log.error("%s", exc)  # throttled: a full disk fails every miss; the log keeps the paths
        what = public(request, exc.what)
        if exc.full:
            return error(507, ["store"], what, "store_full")
        return error(503, ["store"], what, "store_unwritable", {"Retry-After": "10"})

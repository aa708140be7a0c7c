"""The GI-map payload: one binary format for the stored files and the HTTP responses (no base64).

Layout (little endian)::

    b"GIM1"  | u32 header length | header (UTF-8 JSON) | section bytes, in the header's order

The header names the sections (``gi``, optional ``di``, ``depth``: name, codec, byte count) and what the map
is: scene, GI camera and its OpenGL matrices, light, resolution, spp and bake cost; a served payload's header
adds ``hit`` and ``timings_ms``. :func:`decode_payload` is the client side: bytes in, arrays and camera out;
bad bytes raise :class:`PayloadError` (a ValueError) naming what is wrong. The fields, the HTTP endpoints and
their error answers: docs/architecture.md, GI-map payload.
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass
from typing import Any

import numpy as np

from baseline_cloudbaking.codecs import DEPTH_CODEC, Pillow8Bit, get_codec
from gicore.camera import Camera

MAGIC = b"GIM1"
MEDIA_TYPE = "application/vnd.gigan.gimap"
_LEN = struct.Struct("<I")
#: Headers are small JSON objects; anything larger is not a payload of ours.
MAX_HEADER_BYTES = 1 << 16
SECTIONS = ("gi", "di", "depth")


class PayloadError(ValueError):
    """Bytes that are not a well-formed GI-map payload."""


def pack(header: dict[str, Any], sections: dict[str, bytes]) -> bytes:
    """A payload from a header (``sections`` is filled in here) and named section bytes."""
    unknown = set(sections) - set(SECTIONS)
    if unknown:
        raise ValueError(f"unknown payload sections {sorted(unknown)}; known: {SECTIONS}")
    codecs = {"gi": header["codec"], "di": header["codec"], "depth": DEPTH_CODEC.name}
    header = header | {
        "sections": [{"name": n, "codec": codecs[n], "bytes": len(sections[n])} for n in SECTIONS if n in sections]
    }
    head = json.dumps(header, separators=(",", ":"), allow_nan=False).encode()
    return b"".join([MAGIC, _LEN.pack(len(head)), head, *(sections[n] for n in SECTIONS if n in sections)])


def unpack(data: bytes) -> tuple[dict[str, Any], dict[str, memoryview]]:
    """Header and section views of a payload, without decoding any image."""
    view = memoryview(data)
    if len(view) < len(MAGIC) + _LEN.size or bytes(view[:4]) != MAGIC:
        raise PayloadError(f"not a GI-map payload: it does not start with {MAGIC!r}")
    (n,) = _LEN.unpack_from(view, 4)
    start = 4 + _LEN.size
    if n > MAX_HEADER_BYTES or start + n > len(view):
        raise PayloadError(f"header length {n} does not fit a {len(view)}-byte payload")
    try:
        header = json.loads(bytes(view[start : start + n]))
        specs = [(s["name"], int(s["bytes"])) for s in header["sections"]]
    except (ValueError, KeyError, TypeError) as exc:
        raise PayloadError(f"payload header is not valid: {exc}") from None
    offset = start + n
    sections = {}
    for name, size in specs:
        if size < 0 or offset + size > len(view):
            raise PayloadError(f"section {name!r} ({size} bytes) runs past the end of the payload")
        sections[name] = view[offset : offset + size]
        offset += size
    if offset != len(view):
        raise PayloadError(f"{len(view) - offset} bytes follow the last section")
    return header, sections


def with_header(data: bytes, extra: dict[str, Any], drop: tuple[str, ...] = ()) -> bytes:
    """The payload ``data`` with ``extra`` merged into its header and the sections in ``drop`` removed
    (the sections are copied, not re-encoded). Where no section is dropped and no key of ``extra`` is in the
    header, ``extra`` is spliced into the header's JSON text instead of encoding the header again (a server
    does this per hit: re-encoding the camera and matrices was a third of a hit's own time)."""
    header, sections = unpack(data)
    if not extra or set(extra) & header.keys() or set(drop) & sections.keys():
        header.pop("sections")
        return pack(header | extra, {n: bytes(v) for n, v in sections.items() if n not in drop})
    (n,) = _LEN.unpack_from(data, 4)
    start = 4 + _LEN.size
    added = json.dumps(extra, separators=(",", ":"), allow_nan=False).encode()
    head = bytes(data[start : start + n]).rstrip()[:-1] + b"," + added[1:]  # ...} + ,"k":v...}
    return b"".join([MAGIC, _LEN.pack(len(head)), head, memoryview(data)[start + n :]])


@dataclass(frozen=True)
class GIMapPayload:
    """A decoded payload: the GI map (``gi`` linear, or ``display``: an 8-bit codec's HxWx3 uint8 values, when
    asked to keep them) and what warping and composition need, at the GI ``camera``."""

    header: dict[str, Any]
    camera: Camera
    view: np.ndarray
    proj: np.ndarray
    gi: np.ndarray | None
    di: np.ndarray | None
    depth: np.ndarray
    display: np.ndarray | None = None

    @classmethod
    def of(
        cls,
        header: dict[str, Any],
        gi: np.ndarray | None,
        di: np.ndarray | None,
        depth: np.ndarray,
        display: np.ndarray | None = None,
    ) -> GIMapPayload:
        """A payload from its header and its decoded sections (``gi`` or ``display``); :class:`PayloadError` when
        they do not fit the header's camera."""
        try:
            camera = Camera.from_dict(header["camera"])
        except (KeyError, TypeError, ValueError) as exc:
            raise PayloadError(f"payload header is not valid: {exc}") from None
        shape = (camera.height, camera.width)
        image = gi if gi is not None else display
        if (
            image is None
            or image.shape[:2] != shape
            or depth.shape != shape
            or (di is not None and di.shape != image.shape)
        ):
            got = "no map" if image is None else f"gi {image.shape}"
            raise PayloadError(f"sections do not match the {shape[1]}x{shape[0]} camera: {got}, depth {depth.shape}")
        return cls(header, camera, np.asarray(header["view"]), np.asarray(header["proj"]), gi, di, depth, display)

    @property
    def hit(self) -> bool | None:
        """Served from the GI tree (True), rendered for this request (False), or a stored file (None)."""
        return self.header.get("hit")

    @property
    def timings_ms(self) -> dict[str, float]:
        return self.header.get("timings_ms", {})


def decode_payload(data: bytes, display: bool = False) -> GIMapPayload:
    """Decode a payload (a server response or a stored file) into arrays and the GI camera. ``display``: an 8-bit
    codec's map stays as its display values (``GIMapPayload.display``; a GL warp decodes them on the GPU)."""
    header, sections = unpack(data)
    if "gi" not in sections or "depth" not in sections:
        raise PayloadError(f"payload lacks the gi or depth section; it has {sorted(sections)}")
    try:
        codec = get_codec(header["codec"])
    except (KeyError, ValueError) as exc:
        raise PayloadError(f"payload header is not valid: {exc}") from None
    # the codecs read the sections where they lie in ``data`` (no copies); a CodecError (a ValueError) names the codec
    di = codec.decode(sections["di"]) if "di" in sections else None
    depth = DEPTH_CODEC.decode(sections["depth"])
    if display and isinstance(codec, Pillow8Bit):
        return GIMapPayload.of(header, None, di, depth, codec.decode_display(sections["gi"]))
    return GIMapPayload.of(header, codec.decode(sections["gi"]), di, depth)

"""GI-map codecs: one :class:`Codec` protocol, a registry, and the measurement every codec reports.

``jpeg``, ``webp``, ``avif``, ``png``: 8-bit, through the project's tone map (:func:`gicore.tonemap.tonemap`),
decoded back through its inverse (:func:`gicore.tonemap.linear_of_display`: a 256-entry table), or kept as the
8-bit display values for a GL warp to decode on the GPU (:meth:`Pillow8Bit.decode_display`);
``exr-half``: OpenEXR half float; ``zstd-f16``: zstandard on the raw float16
array; ``jpeg:75`` and the like set an 8-bit codec's quality (:func:`get_codec`). ``Codec.quantize`` is a
codec's exact domain (a lossless codec decodes to it bit for bit) and ``Codec.max_rmse`` its stated tone-mapped
error bound on rendered maps (both tested); :func:`measure` reports bytes, encode and decode time, and the
actual error. Depth travels with :data:`DEPTH_CODEC` (float16, delta-coded rows, split byte planes, zstandard):
relative error <= 2^-11, far below the structure-aware warp's depth test. docs/architecture.md, Codecs.
"""

from __future__ import annotations

import io
import struct
import time
from dataclasses import dataclass, replace
from typing import Literal, Protocol

import numpy as np
import zstandard

from gicore.metrics import rmse, ssim
from gicore.tonemap import linear_of_display, tonemap

_F16_MAX = float(np.finfo(np.float16).max)
_SHAPE = struct.Struct("<III")
#: Bytes of the shape header before a zstd-coded array's compressed bytes (the depth section's, say).
ARRAY_HEADER_BYTES = _SHAPE.size
#: Largest side a zstd-coded array may claim (a corrupt header must not allocate gigabytes).
_MAX_SIDE = 16384
ZSTD_LEVEL = 3


class CodecError(ValueError):
    """Bytes that a codec cannot decode (truncated, corrupt, or another codec's)."""


class Codec(Protocol):
    """Encodes a linear HxWx3 float32 map (values >= 0) to bytes and back."""

    name: str
    #: ``decode(encode(x)) == quantize(x)`` exactly.
    lossless: bool
    #: Stated bound on the tone-mapped RMSE against the source for rendered GI maps.
    max_rmse: float

    def quantize(self, image: np.ndarray) -> np.ndarray: ...

    def encode(self, image: np.ndarray) -> bytes: ...

    def decode(self, data: bytes | memoryview) -> np.ndarray: ...


def _check_map(image: np.ndarray) -> np.ndarray:
    img = np.asarray(image, dtype=np.float32)
    if img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"a GI map must be HxWx3, got shape {img.shape}")
    if not np.all(np.isfinite(img)):
        raise ValueError("a GI map must be finite; it contains NaN or Inf")
    return np.maximum(img, 0.0)


@dataclass(frozen=True)
class Pillow8Bit:
    """An 8-bit Pillow format on the tone-mapped map; ``options`` go to ``Image.save``."""

    name: str
    format: str
    options: tuple[tuple[str, int], ...]
    lossless: bool
    max_rmse: float

    def _to_u8(self, image: np.ndarray) -> np.ndarray:
        return np.rint(tonemap(_check_map(image)) * 255.0).astype(np.uint8)

    def quantize(self, image: np.ndarray) -> np.ndarray:
        return linear_of_display(self._to_u8(image))

    def encode(self, image: np.ndarray) -> bytes:
        from PIL import Image

        buf = io.BytesIO()
        Image.fromarray(self._to_u8(image), "RGB").save(buf, format=self.format, **dict(self.options))
        return buf.getvalue()

    def decode(self, data: bytes | memoryview) -> np.ndarray:
        return linear_of_display(self.decode_display(data))

    def decode_display(self, data: bytes | memoryview) -> np.ndarray:
        """The 8-bit display values (HxWx3 uint8) the bytes hold, not yet turned into linear radiance."""
        from PIL import Image, UnidentifiedImageError

        try:
            with Image.open(io.BytesIO(data)) as im:
                if im.format != self.format:
                    raise CodecError(f"{self.name}: the bytes hold {im.format}, not {self.format}")
                q = np.asarray(im if im.mode == "RGB" else im.convert("RGB"))
        except (UnidentifiedImageError, OSError, SyntaxError) as exc:
            raise CodecError(f"{self.name}: cannot decode {len(data)} bytes ({exc})") from None
        return q


def _half(image: np.ndarray) -> np.ndarray:
    return np.minimum(_check_map(image), _F16_MAX).astype(np.float16)


@dataclass(frozen=True)
class _HalfFloat:
    """The float16 codecs' common part: lossless on the float16-rounded map (clipped at 65504)."""

    lossless: bool = True
    max_rmse: float = 1e-3

    def quantize(self, image: np.ndarray) -> np.ndarray:
        return _half(image).astype(np.float32)


@dataclass(frozen=True)
class ExrHalf(_HalfFloat):
    """OpenEXR, one RGB half-float part, ZIP compression."""

    name: str = "exr-half"

    def encode(self, image: np.ndarray) -> bytes:
        import OpenEXR

        header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
        buf = io.BytesIO()
        OpenEXR.File(header, {"RGB": np.ascontiguousarray(_half(image))}).write(buf)
        return buf.getvalue()

    def decode(self, data: bytes | memoryview) -> np.ndarray:
        import OpenEXR

        try:
            channels = OpenEXR.File(io.BytesIO(data)).channels()
            rgb = channels["RGB"].pixels
        except (RuntimeError, KeyError, ValueError) as exc:  # the OpenEXR bindings raise RuntimeError on bad bytes
            raise CodecError(f"{self.name}: cannot decode {len(data)} bytes ({exc})") from None
        return np.asarray(rgb, dtype=np.float32)


def _pack_array(arr: np.ndarray, shuffle: bool) -> bytes:
    """Shape header + zstd of the array's bytes (byte planes first when ``shuffle``)."""
    h, w = arr.shape[:2]
    c = arr.shape[2] if arr.ndim == 3 else 0
    raw = np.ascontiguousarray(arr).view(np.uint8).reshape(-1, arr.itemsize).T.tobytes() if shuffle else arr.tobytes()
    return _SHAPE.pack(h, w, c) + zstandard.ZstdCompressor(level=ZSTD_LEVEL).compress(raw)


def _unpack_array(name: str, data: bytes | memoryview, dtype: type, shuffle: bool) -> np.ndarray:
    if len(data) < _SHAPE.size:
        raise CodecError(f"{name}: {len(data)} bytes is shorter than its header")
    h, w, c = _SHAPE.unpack_from(data)
    if not (0 < h <= _MAX_SIDE and 0 < w <= _MAX_SIDE and c <= 4):
        raise CodecError(f"{name}: the header's shape {h}x{w}x{c} is not a map's")
    itemsize = np.dtype(dtype).itemsize
    n = h * w * max(c, 1)
    try:
        raw = zstandard.ZstdDecompressor().decompress(data[_SHAPE.size :], max_output_size=n * itemsize)
    except zstandard.ZstdError as exc:
        raise CodecError(f"{name}: cannot decompress ({exc})") from None
    if len(raw) != n * itemsize:
        raise CodecError(
            f"{name}: {len(raw)} bytes decompressed, the header says {h}x{w}x{c} of {itemsize}-byte values"
        )
    buf = np.frombuffer(raw, dtype=np.uint8)
    if shuffle:  # byte planes back to values: plane k holds byte k (little endian) of every value
        planes = buf.reshape(itemsize, n)
        value = np.zeros(n, np.dtype(f"<u{itemsize}"))
        for k in range(itemsize):  # shifts and ors: a tenth of the time of a transposing copy
            value |= planes[k].astype(value.dtype) << (8 * k)
        buf = value.view(np.uint8)
    arr = buf.view(dtype)
    return arr.reshape((h, w, c) if c else (h, w))


@dataclass(frozen=True)
class ZstdF16(_HalfFloat):
    """zstandard on the raw float16 array."""

    name: str = "zstd-f16"

    def encode(self, image: np.ndarray) -> bytes:
        return _pack_array(np.ascontiguousarray(_half(image)), shuffle=False)

    def decode(self, data: bytes | memoryview) -> np.ndarray:
        arr = _unpack_array(self.name, data, np.float16, shuffle=False)
        if arr.ndim != 3 or arr.shape[2] != 3:
            raise CodecError(f"{self.name}: expected an HxWx3 map, got {arr.shape}")
        return arr.astype(np.float32)


@dataclass(frozen=True)
class DepthF16:
    """Linear view depth (HxW float32, 0 = background) as float16 bit patterns, delta-coded along rows
    (mod 2^16, so exact), byte planes split, zstandard. Decodes to the float16-rounded depth exactly."""

    name: str = "zstd-f16-delta"
    #: Bound on |decoded - depth| / depth: float16's unit roundoff.
    max_rel_error: float = 2.0**-11

    def quantize(self, depth: np.ndarray) -> np.ndarray:
        return self._check(depth).astype(np.float16).astype(np.float32)

    @staticmethod
    def _check(depth: np.ndarray) -> np.ndarray:
        d = np.asarray(depth)
        if d.ndim != 2 or d.dtype != np.float32:
            raise ValueError(f"depth must be an HxW float32 array, got {d.dtype} {d.shape}")
        if not np.all(np.isfinite(d)) or d.min(initial=0.0) < 0.0 or d.max(initial=0.0) > _F16_MAX:
            raise ValueError(f"depth must be finite and in [0, {_F16_MAX:g}]")
        return d

    def encode(self, depth: np.ndarray) -> bytes:
        bits = self._check(depth).astype(np.float16).view(np.uint16)
        return _pack_array(np.diff(bits, axis=1, prepend=np.uint16(0)), shuffle=True)

    def decode(self, data: bytes | memoryview) -> np.ndarray:
        delta = _unpack_array(self.name, data, np.uint16, shuffle=True)
        if delta.ndim != 2:
            raise CodecError(f"{self.name}: expected an HxW depth map, got {delta.shape}")
        return np.cumsum(delta, axis=1, dtype=np.uint16).view(np.float16).astype(np.float32)


#: Every image codec by name. Settings: JPEG quality 90 (4:2:0), WebP quality 90 method 4, AVIF
#: quality 80 speed 8, PNG compress level 1.
CODECS: dict[str, Codec] = {
    c.name: c
    for c in (
        Pillow8Bit("jpeg", "JPEG", (("quality", 90),), lossless=False, max_rmse=0.025),
        Pillow8Bit("webp", "WEBP", (("quality", 90), ("method", 4)), lossless=False, max_rmse=0.02),
        Pillow8Bit("avif", "AVIF", (("quality", 80), ("speed", 8)), lossless=False, max_rmse=0.02),
        Pillow8Bit("png", "PNG", (("compress_level", 1),), lossless=True, max_rmse=0.003),
        ExrHalf(),
        ZstdF16(),
    )
}
CODEC_NAMES: tuple[str, ...] = tuple(CODECS)
#: The codec a client, a prebake, a request and a bench use unless told otherwise (the one declaration).
DEFAULT_CODEC = "jpeg"
#: A codec name as an option or a request field: one of :data:`CODEC_NAMES`.
CodecName = Literal[CODEC_NAMES]  # type: ignore[valid-type]
DEPTH_CODEC = DepthF16()


#: The Pillow option that sets each 8-bit codec's quality (``NAME:QUALITY``, 1 to 100).
QUALITY_OPTION = {"jpeg": "quality", "webp": "quality", "avif": "quality"}


def get_codec(spec: str) -> Codec:
    """The codec ``NAME``, or ``NAME:QUALITY`` for the codecs of :data:`QUALITY_OPTION`: the registry's settings
    with the quality (1 to 100) replaced, named ``spec``. ValueError lists what is known (also for a ``spec`` that is
    not a string, as a payload header may hold)."""
    if not isinstance(spec, str):
        known = ", ".join(CODEC_NAMES)
        raise ValueError(f"a codec is named by a string, not {type(spec).__name__}; known codecs: {known}")
    name, sep, quality = spec.partition(":")
    try:
        codec = CODECS[name]
    except KeyError:
        raise ValueError(f"unknown codec {name!r}; known codecs: {', '.join(CODEC_NAMES)}") from None
    if not sep:
        return codec
    if not (
        isinstance(codec, Pillow8Bit) and name in QUALITY_OPTION and quality.isdigit() and 1 <= int(quality) <= 100
    ):
        raise ValueError(f"codec {spec!r}: a quality 1 to 100 is known for {', '.join(QUALITY_OPTION)} only")
    options = tuple((k, int(quality) if k == QUALITY_OPTION[name] else v) for k, v in codec.options)
    return replace(codec, name=spec, options=options)


@dataclass(frozen=True)
class CodecReport:
    """One encode/decode of one map: size, times, and the error against the source (tone-mapped)."""

    codec: str
    bytes: int
    encode_ms: float
    decode_ms: float
    rmse: float
    ssim: float


def measure(codec: Codec, image: np.ndarray) -> tuple[CodecReport, bytes, np.ndarray]:
    """Encode and decode ``image`` once with ``codec``; returns the report, the bytes and the decoded map."""
    t0 = time.perf_counter()
    data = codec.encode(image)
    t1 = time.perf_counter()
    decoded = codec.decode(data)
    t2 = time.perf_counter()
    src, dec = tonemap(_check_map(image)), tonemap(decoded)
    report = CodecReport(codec.name, len(data), (t1 - t0) * 1e3, (t2 - t1) * 1e3, rmse(dec, src), ssim(dec, src))
    return report, data, decoded

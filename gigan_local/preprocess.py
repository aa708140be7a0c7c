"""Network I/O: the one place that turns frame buffers into network values and back (numpy only).

Training (``gigan_local.data``), export and the onnxruntime client (``gigan_local.inference``) all call
these functions, so a model sees exactly the same encoding everywhere. Every network value lies in
``[-1, 1]``, the range of the generator's tanh output:

========== ====== ===========================================================================
buffer     chans  encoding
========== ====== ===========================================================================
``di``     3      ``to_signed(tonemap(x))`` -- the same tone map as the target and the metrics
``gt``     3      (target only) ``to_signed(tonemap(x))``; :func:`output_to_radiance` inverts it
``albedo`` 3      ``2a - 1`` (reflectance in [0, 1], clipped)
``normal`` 3      as is: unit view-space normals are already in [-1, 1]; background stays 0
``depth``  1      ``to_signed(d / (d + s))``: background (d = 0) is -1, d = s is 0, far is -> 1
``mask``   1      ``2m - 1``
========== ====== ===========================================================================

Depth uses a scale ``s`` (``InputSpec.depth_scale``) rather than a per-frame min/max so that one depth
means one value in every frame; training sets ``s`` to the median foreground depth of its data (so the
encoded depths spread around 0) and the exported model carries it in ``model.json``. World position is
not an input: it depends on where the scene sits in the world, not on what the camera sees.

A model with ``InputSpec.albedo_floor`` set is albedo-demodulated: ``di`` and ``gt`` are divided by
:func:`albedo_divisor` before the tone map (shading: light, not colour); :func:`output_to_radiance` multiplies it back.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from gicore.buffers import CHANNELS, GENERATOR_INPUTS, TARGET, check_buffer_names
from gicore.config import strict_from_dict
from gicore.tonemap import from_signed, inverse_tonemap, to_signed, tonemap

#: Buffers a network may take as input (those with an encoding in the table above).
INPUT_BUFFERS: tuple[str, ...] = ("di", "albedo", "normal", "depth", "mask")
#: The albedo floor of a demodulated model (``gigan-train --demodulate``): 0.05 is just above the glossy coating's
#: reflectance at normal incidence (0.034 at IOR 1.45), so a channel whose diffuse albedo is near 0 (a saturated
#: colour's) keeps a shading of the same order as the other channels instead of its specular light times 1/albedo;
#: and a silhouette pixel whose one G-buffer sample is a dark object while its GT also averages the white floor
#: (albedo 0.8) is inflated at most 16-fold. Lower floors divide the coating's white light by ever smaller numbers.
ALBEDO_FLOOR = 0.05


@dataclass(frozen=True)
class InputSpec:
    """What a generator takes as input: which buffers, in which channel order, and the depth scale."""

    #: Buffers concatenated along channels in this order (see the module table for each encoding).
    buffers: tuple[str, ...] = GENERATOR_INPUTS
    #: View depth that encodes to 0 (i.e. d / (d + s) = 0.5); in scene units, > 0.
    depth_scale: float = 1.0
    #: None: the DI input and the output are radiance. A floor in (0, 1]: both are shading, radiance divided by
    #: :func:`albedo_divisor` with this floor (``albedo`` must be an input). A model.json without it: radiance.
    albedo_floor: float | None = None

    def __post_init__(self) -> None:
        buffers = check_buffer_names(list(self.buffers))
        bad = [b for b in buffers if b not in INPUT_BUFFERS]
        if bad:
            raise ValueError(f"buffer(s) {bad} cannot be network inputs; choose from {list(INPUT_BUFFERS)}")
        if not buffers:
            raise ValueError(f"the input buffer list is empty; give at least one of {list(INPUT_BUFFERS)}")
        if not (np.isfinite(self.depth_scale) and self.depth_scale > 0):
            raise ValueError(f"depth_scale must be a positive number (a typical view depth), got {self.depth_scale}")
        if self.albedo_floor is not None:
            if not 0.0 < self.albedo_floor <= 1.0:
                raise ValueError(f"albedo_floor must be in (0, 1] or absent, got {self.albedo_floor}")
            if "albedo" not in buffers:
                raise ValueError("an albedo-demodulated model needs 'albedo' among its input buffers")
        object.__setattr__(self, "buffers", buffers)

    @property
    def in_channels(self) -> int:
        """Number of network input channels these buffers make."""
        return sum(CHANNELS[b] for b in self.buffers)

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"buffers": list(self.buffers), "depth_scale": float(self.depth_scale)}
        return d if self.albedo_floor is None else d | {"albedo_floor": float(self.albedo_floor)}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> InputSpec:
        return strict_from_dict(cls, d, "input")


def shaped(name: str, arr: np.ndarray) -> np.ndarray:
    """Buffer ``name`` as a float32 array, a ValueError unless it is HxW x its channels."""
    arr = np.asarray(arr, dtype=np.float32)
    if arr.ndim != 3 or arr.shape[-1] != CHANNELS[name]:
        raise ValueError(f"buffer {name!r} must be an HxWx{CHANNELS[name]} array, got shape {arr.shape}")
    return arr


def require_buffers(frame: dict[str, np.ndarray], spec: InputSpec) -> None:
    """KeyError naming the buffers ``spec`` needs that ``frame`` lacks."""
    missing = [b for b in spec.buffers if b not in frame]
    if missing:
        raise KeyError(f"the frame lacks buffer(s) {missing} that the model needs (it has {sorted(frame)})")


def _checked(name: str, arr: np.ndarray) -> np.ndarray:
    arr = shaped(name, arr)
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"buffer {name!r} contains NaN or Inf; fix the renderer output before feeding a network")
    return arr


def encode_buffer(name: str, arr: np.ndarray, depth_scale: float = 1.0, out: np.ndarray | None = None) -> np.ndarray:
    """Encode one HxWxC buffer into network values in [-1, 1] (HxWxC float32); into ``out`` when given (an
    HxWxC float32 array or view, e.g. the buffer's channels of a CxHxW network input, transposed)."""
    arr = _checked(name, arr)
    if name in ("di", "gt"):
        value = to_signed(tonemap(arr))
    elif name in ("albedo", "mask"):
        value = 2.0 * np.clip(arr, 0.0, 1.0) - 1.0
    elif name == "normal":
        value = arr
    elif name == "depth":
        d = np.maximum(arr, 0.0)
        value = to_signed(d / (d + np.float32(depth_scale)))
    else:
        raise ValueError(
            f"buffer {name!r} has no network encoding; inputs are {list(INPUT_BUFFERS)}, target {TARGET!r}"
        )
    if out is None:
        return value.astype(np.float32, copy=False)
    np.copyto(out, value)
    return out


def frame_to_input(
    frame: dict[str, np.ndarray], spec: InputSpec, out: np.ndarray | None = None, divisor: np.ndarray | None = None
) -> np.ndarray:
    """Frame buffers (name -> HxWxC linear arrays) to the network input, CxHxW float32 in [-1, 1], written
    into ``out`` (CxHxW float32, e.g. a model's preallocated input) when given: each buffer is encoded
    straight into its channels, with no concatenated copy. A demodulated model's DI is divided by ``divisor``, the
    frame's :func:`frame_divisor` (computed here unless the caller, who needs it to decode, passes it)."""
    require_buffers(frame, spec)
    sizes = {b: np.shape(frame[b])[:2] for b in spec.buffers}
    if len(set(sizes.values())) != 1:
        raise ValueError(f"the frame's buffers differ in size: {sizes}")
    shape = (spec.in_channels, *sizes[spec.buffers[0]])
    if out is None:
        out = np.empty(shape, dtype=np.float32)
    elif out.shape != shape or out.dtype != np.float32:
        raise ValueError(f"the input buffer is {out.dtype} {out.shape}, but these buffers make float32 {shape}")
    start = 0
    for b in spec.buffers:
        arr = frame[b]
        if b == "di" and spec.albedo_floor is not None:  # NaN or Inf stays so through it: the encoding refuses it
            arr = np.asarray(arr, np.float32) / (frame_divisor(frame, spec) if divisor is None else divisor)
        encode_buffer(b, arr, spec.depth_scale, out=out[start : start + CHANNELS[b]].transpose(1, 2, 0))
        start += CHANNELS[b]
    return out


def frame_to_target(frame: dict[str, np.ndarray], spec: InputSpec) -> np.ndarray:
    """The frame's ground-truth GI as the target of a network of ``spec``, 3xHxW float32 in [-1, 1]."""
    if TARGET not in frame:
        raise KeyError(f"the frame lacks the target buffer {TARGET!r} (it has {sorted(frame)})")
    divisor = frame_divisor(frame, spec)
    gt = frame[TARGET] if divisor is None else np.asarray(frame[TARGET], np.float32) / divisor
    return np.ascontiguousarray(encode_buffer(TARGET, gt).transpose(2, 0, 1))


def albedo_divisor(albedo: np.ndarray, floor: float) -> np.ndarray:
    """What a demodulated model's radiance is divided by (and its output multiplied by): per channel
    max(albedo, ``floor``) where a surface was hit, 1 where none was (albedo 0 in every channel: the background,
    whose radiance is kept). HxWx3 float32."""
    a = shaped("albedo", albedo)
    divisor = np.clip(a, np.float32(floor), np.float32(1.0))  # max(clip(a, 0, 1), floor), as floor > 0
    # per-channel maxima, not a.max(axis=-1): a reduction over a 3-wide last axis is several times slower
    divisor[np.maximum(np.maximum(a[..., 0], a[..., 1]), a[..., 2]) <= 0.0] = 1.0
    return divisor


def frame_divisor(frame: dict[str, np.ndarray], spec: InputSpec) -> np.ndarray | None:
    """What a model of ``spec`` divides the frame's radiance by: :func:`albedo_divisor` of its albedo for a
    demodulated model, None for a radiance one."""
    return None if spec.albedo_floor is None else albedo_divisor(frame["albedo"], spec.albedo_floor)


def input_albedo(x: np.ndarray, spec: InputSpec) -> np.ndarray:
    """The albedo (HxWx3 in [0, 1]) that the network input ``x`` (CxHxW, :func:`frame_to_input`) encodes."""
    start = sum(CHANNELS[b] for b in spec.buffers[: spec.buffers.index("albedo")])
    return np.ascontiguousarray((np.asarray(x[start : start + 3], np.float32).transpose(1, 2, 0) + 1.0) * 0.5)


def output_to_display(y: np.ndarray) -> np.ndarray:
    """Network output 3xHxW in [-1, 1] to tone-mapped display values HxWx3 in [0, 1] of what it encodes,
    C-contiguous (the transpose is copied once, so what follows runs on contiguous memory)."""
    y = np.asarray(y, dtype=np.float32)
    if y.ndim != 3 or y.shape[0] != 3:
        raise ValueError(f"expected a 3xHxW network output, got shape {y.shape}")
    return from_signed(np.ascontiguousarray(y.transpose(1, 2, 0))).astype(np.float32, copy=False)


def output_to_radiance(y: np.ndarray, spec: InputSpec, divisor: np.ndarray | None = None) -> np.ndarray:
    """Network output 3xHxW in [-1, 1] of a model of ``spec`` to linear GI radiance HxWx3 (inverse of the target
    encoding): every GI map a model makes comes from here. A demodulated model's is multiplied by ``divisor``, the
    frame's :func:`frame_divisor`."""
    radiance = inverse_tonemap(output_to_display(y))
    if spec.albedo_floor is None:
        return radiance
    if divisor is None:
        raise ValueError("an albedo-demodulated model's output needs the frame's albedo divisor to become radiance")
    radiance *= divisor
    return radiance

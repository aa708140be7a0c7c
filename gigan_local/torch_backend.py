"""GIGAN's generator on torch: the weights of an exported ONNX file in the torch network they came from.

:class:`TorchGIModel` is :class:`gigan_local.inference.ExportedGenerator` on torch: the generator that
``model.json``'s ``network`` describes (:func:`gigan_local.networks.define_G`), its weights read back from
the file (:func:`gigan_local.warmstart.load_into`: batch norms the exporter folded into their convolutions
come back exactly in eval mode), in eval mode. On a CUDA device it runs in float16, which every GPU that
current torch builds support computes natively. :meth:`TorchGIModel.predict` copies the frame's raw buffers
to the device, encodes them there (:func:`encode_frame`, the torch twin of
:func:`gigan_local.preprocess.frame_to_input`), runs the network, decodes its output to radiance there
(:func:`decode_output`) and copies that back: a client's ``inference`` stage counts both copies, and no
per-pixel encoding runs on the host. On CUDA, that device work is captured once as a CUDA graph
(:class:`CapturedForward`): a U-Net launches a few hundred small kernels per frame, and replaying them as one
graph takes their launch cost off the host. Without CUDA it runs on the CPU in float32, where it matches
onnxruntime on the same file to float rounding.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import numpy as np

from gicore.buffers import CHANNELS
from gicore.error_policy import UserError
from gicore.tonemap import GAMMA, Y_MAX
from gigan_local.inference import MODEL_JSON, ExportedGenerator, check_input_shape
from gigan_local.preprocess import InputSpec, require_buffers, shaped


class TorchGIModel(ExportedGenerator):
    """The exported generator on torch: float16 on the CUDA device where torch sees one, else float32 on the
    CPU with ``threads`` intra-op threads (torch's setting for the whole process)."""

    def _load(self, threads: int, shape: tuple[int, int, int, int]) -> None:
        import onnx
        import torch

        net = torch_generator(self.path, self.config)
        graph_input = onnx.load(str(self.path)).graph.input[0]
        check_input_shape(self, [d.dim_value or d.dim_param for d in graph_input.type.tensor_type.shape.dim][1:], shape)
        if torch.cuda.is_available():
            self.device, self.dtype = torch.device("cuda"), torch.float16
            torch.backends.cudnn.benchmark = True  # one input shape: let cuDNN pick its fastest kernels once
        else:
            self.device, self.dtype = torch.device("cpu"), torch.float32
            torch.set_num_threads(threads)
        self.net = net.to(self.device, self.dtype)
        name = torch.cuda.get_device_name(self.device) if self.device.type == "cuda" else "cpu"
        self.backend = f"torch {self.device.type} {str(self.dtype).removeprefix('torch.')} ({name})"
        self._captured: CapturedForward | None = None
        if self.device.type == "cuda":
            size = shape[2:]
            blank = {b: np.zeros((*size, CHANNELS[b]), np.float32) for b in self.spec.buffers}
            try:
                self._captured = CapturedForward(self._forward, blank, self.device)
                self.backend += ", CUDA graph"
            except RuntimeError as e:  # a capture the device or driver refuses: eager kernels still work
                print(f"notice: no CUDA graph ({e}); inference launches its kernels one by one", file=sys.stderr)

    def _input_array(self, shape: tuple[int, ...]) -> np.ndarray:
        import torch

        # pinned host memory: the copy to the device is a direct DMA, not staged through a bounce buffer
        self._host_input: Any = torch.zeros(shape, dtype=torch.float32, pin_memory=self.device.type == "cuda")
        return self._host_input.numpy()

    def predict(self, frame_buffers: dict[str, np.ndarray]) -> np.ndarray:
        """Linear GI radiance (HxWx3 float32) from the frame's buffers: encoded, predicted and decoded on the
        device (see the module docstring); a NaN or Inf in a buffer is a ValueError, as on the host path."""
        import torch

        require_buffers(frame_buffers, self.spec)
        self.check_frame_size(frame_buffers)
        # contiguous: torch takes no negative strides (a read-back flipped upright is such a view)
        host = {b: np.ascontiguousarray(shaped(b, frame_buffers[b])) for b in self.spec.buffers}
        with torch.inference_mode():
            if self._captured is not None:
                radiance, finite = self._captured(host)
            else:
                radiance, finite = self._forward({b: torch.from_numpy(a).to(self.device) for b, a in host.items()})
            out, finite = radiance.cpu().numpy(), finite.cpu().numpy()  # .cpu() waits for the device
        if not finite.all():
            bad = [b for b, ok in zip(host, finite) if not ok]
            raise ValueError(f"buffer(s) {bad} contain NaN or Inf; fix the renderer output before feeding a network")
        return out

    def _forward(self, raw: dict[str, Any]) -> tuple[Any, Any]:
        """Radiance (HxWx3 float32) and per-buffer finiteness from raw HxWxC tensors on the device."""
        import torch

        finite = torch.stack([torch.isfinite(t).all() for t in raw.values()])
        x = encode_frame(raw, self.spec).to(self.dtype)
        return decode_output(self.net(x[None])[0].float(), self.spec, raw.get("albedo")), finite

    def _run(self, x: np.ndarray) -> np.ndarray:
        import torch

        with torch.inference_mode():
            host = self._host_input if x is self._input else torch.from_numpy(x)  # the pinned tensor itself
            x_device = host.to(self.device, non_blocking=True).to(self.dtype)
            # .cpu() waits for the device, so the time of the whole call is what the network took
            return self.net(x_device)[0].float().cpu().numpy()


def torch_generator(path: Path, config: dict[str, Any]) -> Any:
    """The torch generator that ``model.json`` ``config`` describes, with the weights of the exported file
    ``path`` (:func:`gigan_local.warmstart.load_into`), float32 on the CPU in eval mode; a UserError naming the
    file where ``config`` has no architecture."""
    from gigan_local.config import NetworkConfig
    from gigan_local.networks import define_G
    from gigan_local.warmstart import load_into

    try:
        network = NetworkConfig.from_dict(config["network"])
    except (KeyError, TypeError, ValueError) as e:
        raise UserError(
            f"{path.parent / MODEL_JSON} has no generator architecture ({type(e).__name__}: {e}), which the torch "
            "backend builds",
            "run it with --inference onnxruntime, or re-export it with gigan-export",
        ) from None
    net = define_G(network)
    load_into(net, path, network, InputSpec.from_dict(config["input"]), calibration=None)
    return net.eval()


def encode_frame(raw: dict[str, Any], spec: InputSpec) -> Any:
    """The network input (CxHxW float32 in [-1, 1]) from raw HxWxC tensors: the encoding of
    :func:`gigan_local.preprocess.encode_buffer`, on the tensors' device."""
    import torch

    def encoded(name: str, t: Any) -> Any:
        if name == "di":
            x = (t if spec.albedo_floor is None else t / albedo_divisor(raw["albedo"], spec.albedo_floor)).clamp_min(
                0.0
            )
            return 2.0 * (x / (1.0 + x)) ** (1.0 / GAMMA) - 1.0
        if name in ("albedo", "mask"):
            return 2.0 * t.clamp(0.0, 1.0) - 1.0
        if name == "normal":
            return t
        if name == "depth":
            d = t.clamp_min(0.0)
            return 2.0 * (d / (d + spec.depth_scale)) - 1.0
        raise ValueError(f"buffer {name!r} has no encoding on the torch backend")

    return torch.cat([encoded(b, raw[b]) for b in spec.buffers], dim=2).permute(2, 0, 1).contiguous()


def decode_output(y: Any, spec: InputSpec, albedo: Any = None) -> Any:
    """Linear radiance (HxWx3, contiguous) from the network output (3xHxW in [-1, 1]) of a model of ``spec``, times
    :func:`albedo_divisor` of the frame's ``albedo`` (HxWx3) for a demodulated one: the decoding of
    :func:`gigan_local.preprocess.output_to_radiance`, on the tensor's device."""
    display = ((y + 1.0) * 0.5).clamp(0.0, Y_MAX) ** GAMMA
    radiance = (display / (1.0 - display)).permute(1, 2, 0)
    if spec.albedo_floor is None:
        return radiance.contiguous()
    if albedo is None:
        raise ValueError("an albedo-demodulated model's output needs the frame's albedo to become radiance")
    return (radiance * albedo_divisor(albedo, spec.albedo_floor)).contiguous()


def albedo_divisor(albedo: Any, floor: float) -> Any:
    """:func:`gigan_local.preprocess.albedo_divisor` of an HxWx3 tensor, on its device."""
    import torch

    a = albedo.clamp(0.0, 1.0)
    return torch.where(a.amax(dim=-1, keepdim=True) > 0.0, a.clamp_min(floor), torch.ones_like(a))


class CapturedForward:
    """``forward`` (raw device tensors -> a tuple of device tensors) on fixed input tensors, captured once as a CUDA
    graph. Calling it copies a frame's host buffers into those tensors and replays the graph: the outputs are the
    same tensors every time, overwritten. The capture follows torch's recipe (warm-up on a side stream, so that
    cuDNN's algorithm search and the allocator's first blocks happen outside the graph), and its first replay
    must give what the last eager warm-up gave: a RuntimeError otherwise, as for a capture the device refuses."""

    WARMUP = 3

    def __init__(self, forward: Any, host: dict[str, np.ndarray], device: Any):
        import torch

        with torch.inference_mode():
            self.inputs = {b: torch.from_numpy(a).to(device) for b, a in host.items()}
            side = torch.cuda.Stream(device)
            side.wait_stream(torch.cuda.current_stream(device))
            with torch.cuda.stream(side):
                for _ in range(self.WARMUP):
                    eager = [t.clone() for t in forward(self.inputs)]
            torch.cuda.current_stream(device).wait_stream(side)
            self.graph = torch.cuda.CUDAGraph()
            with torch.cuda.graph(self.graph):
                self.outputs = forward(self.inputs)
            self.graph.replay()
            if not all(torch.allclose(a, b, rtol=1e-2, atol=1e-3) for a, b in zip(self.outputs, eager)):
                raise RuntimeError("the captured graph's output differs from the eager network's")

    def __call__(self, host: dict[str, np.ndarray]) -> tuple[Any, ...]:
        import torch

        for name, array in host.items():
            self.inputs[name].copy_(torch.from_numpy(array))
        self.graph.replay()
        return self.outputs

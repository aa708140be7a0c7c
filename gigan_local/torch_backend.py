"""GIGAN's generator on torch: the weights of an exported ONNX file in the torch network they came from.

:class:`TorchGIModel` is :class:`gigan_local.inference.ExportedGenerator` on torch: the generator that
``model.json``'s ``network`` describes (:func:`gigan_local.networks.define_G`), its weights read back from
the file (:func:`gigan_local.warmstart.load_into`: batch norms the exporter folded into their convolutions
come back exactly in eval mode), in eval mode. On a CUDA device it runs in float16, which every GPU that
current torch builds support computes natively; the input is encoded into pinned host memory and copied
to the device, and the output copied back, inside :meth:`predict` (so a client's ``inference`` stage
counts the copies). Without CUDA it runs on the CPU in float32, where it matches onnxruntime on the same
file to float rounding.
"""

from __future__ import annotations

import importlib.util
from typing import Any

import numpy as np

from gicore.cuda_probe import cuda_device_count
from gicore.error_policy import UserError
from gigan_local.inference import MODEL_JSON, ExportedGenerator, check_input_shape


def cuda_for_torch() -> bool:
    """Whether torch runs on a CUDA device here. The driver is asked first (:func:`cuda_device_count`), so a
    machine without a GPU does not import torch (about 2 s) to find out."""
    if cuda_device_count() == 0 or importlib.util.find_spec("torch") is None:
        return False
    import torch

    return torch.cuda.is_available()


class TorchGIModel(ExportedGenerator):
    """The exported generator on torch: float16 on the CUDA device where torch sees one, else float32 on the
    CPU with ``threads`` intra-op threads (torch's setting for the whole process)."""

    def _load(self, threads: int, shape: tuple[int, int, int, int]) -> None:
        import onnx
        import torch

        from gigan_local.config import NetworkConfig
        from gigan_local.networks import define_G
        from gigan_local.warmstart import load_into

        try:
            network = NetworkConfig.from_dict(self.config["network"])
        except (KeyError, TypeError, ValueError) as e:
            raise UserError(
                f"{self.path.parent / MODEL_JSON} has no generator architecture ({type(e).__name__}: {e}), which the "
                "torch backend builds",
                "run it with --inference onnxruntime, or re-export it with gigan-export",
            ) from None
        net = define_G(network)
        load_into(net, self.path, network, self.spec, calibration=None)
        graph_input = onnx.load(str(self.path)).graph.input[0]
        check_input_shape(self, [d.dim_value or d.dim_param for d in graph_input.type.tensor_type.shape.dim][1:], shape)
        if torch.cuda.is_available():
            self.device, self.dtype = torch.device("cuda"), torch.float16
            torch.backends.cudnn.benchmark = True  # one input shape: let cuDNN pick its fastest kernels once
        else:
            self.device, self.dtype = torch.device("cpu"), torch.float32
            torch.set_num_threads(threads)
        self.net = net.eval().to(self.device, self.dtype)
        name = torch.cuda.get_device_name(self.device) if self.device.type == "cuda" else "cpu"
        self.backend = f"torch {self.device.type} {str(self.dtype).removeprefix('torch.')} ({name})"

    def _input_array(self, shape: tuple[int, ...]) -> np.ndarray:
        import torch

        # pinned host memory: the copy to the device is a direct DMA, not staged through a bounce buffer
        self._host_input: Any = torch.zeros(shape, dtype=torch.float32, pin_memory=self.device.type == "cuda")
        return self._host_input.numpy()

    def _run(self, x: np.ndarray) -> np.ndarray:
        import torch

        with torch.inference_mode():
            host = self._host_input if x is self._input else torch.from_numpy(x)  # the pinned tensor itself
            x_device = host.to(self.device, non_blocking=True).to(self.dtype)
            # .cpu() waits for the device, so the time of the whole call is what the network took
            return self.net(x_device)[0].float().cpu().numpy()

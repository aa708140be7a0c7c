"""Client-side GI inference (the paper's TensorFlow.js role): an exported generator on onnxruntime or torch.

:class:`ExportedGenerator` loads a file written by ``gigan-export`` together with the ``model.json`` beside
it, checks that the two agree, and turns frame buffers into linear GI radiance with the same encoding as
training (``gigan_local.preprocess``: an albedo-demodulated model's shading is multiplied by the frame's albedo
there); a backend brings only the network's run. :class:`GIModel` runs the
ONNX graph on onnxruntime's CPU provider (needs no torch); :class:`gigan_local.torch_backend.TorchGIModel`
runs the same weights on torch (fp16 on a CUDA GPU); :func:`gigan_local.backend_choice.open_model` picks
one for ``--inference auto|onnxruntime|torch``. A missing, corrupt or mismatched model is a
:class:`~gicore.error_policy.UserError` naming the file.
"""

from __future__ import annotations

import json
from abc import ABC, abstractmethod
from pathlib import Path
from typing import Any

import numpy as np

from gicore.error_policy import UserError
from gigan_local.preprocess import InputSpec, frame_divisor, frame_to_input, output_to_radiance

MODEL_JSON = "model.json"
FORMAT = "gigan-onnx/1"
#: The shipped model (see its MODEL_CARD.md): fp16 weights, half the size of fp32 at the same speed.
DEFAULT_MODEL = Path(__file__).parent / "models" / "gigan_default" / "model_fp16.onnx"


def read_model_json(path: str | Path) -> dict[str, Any]:
    """The ``model.json`` beside the exported model ``path``, checked: its format, input encoding and
    resolution (a UserError naming the file when it is missing or invalid)."""
    config_path = Path(path).parent / MODEL_JSON
    if not config_path.is_file():
        raise UserError(
            f"{config_path} is missing", f"keep the model.json that `gigan-export` wrote beside {Path(path).name}"
        )
    try:
        config = json.loads(config_path.read_text())
        if config.get("format") != FORMAT:
            raise ValueError(f"format is {config.get('format')!r}, expected {FORMAT!r}")
        InputSpec.from_dict(config["input"])
        int(config["resolution"])
        return config
    except (ValueError, KeyError, TypeError, AttributeError) as e:
        raise UserError(
            f"{config_path} is not a valid gigan model config ({type(e).__name__}: {e})",
            "re-export the model with `gigan-export`",
        ) from None


def check_model_option(path: str | Path, option: str = "--model") -> dict[str, Any]:
    """UserError unless ``path`` (given as ``option``) is a file with a valid ``model.json`` beside it: what a
    command checks before it starts work that will need the model. Returns that ``model.json``."""
    if not Path(path).is_file():
        raise UserError(f"{option} {path} is not a file", "give a .onnx file that gigan-export wrote")
    return read_model_json(path)


def model_info(path: str | Path, option: str = "--model") -> dict[str, Any]:
    """What a run records of the exported model ``path`` (given as ``option``): its architecture, precision,
    resolution and size, from the checked ``model.json`` beside it."""
    doc = check_model_option(path, option)
    return {
        "ngf": doc.get("ngf"),
        "precision": next((k for k, v in doc.get("files", {}).items() if v == Path(path).name), "unknown"),
        "model": doc.get("model"),
        "resolution": int(doc["resolution"]),
        "trained_resolution": trained_resolution(doc),
        "size_mib": round(Path(path).stat().st_size / 2**20, 2),
    }


def trained_resolution(doc: dict[str, Any]) -> int:
    """The side the model of ``model.json`` ``doc`` was trained at: its ``resolution`` unless
    :func:`gigan_local.export.resize_export` made it run at another."""
    return int(doc.get("trained_resolution", doc["resolution"]))


def check_model_resolution(path: str | Path, resolution: int, option: str = "--model") -> None:
    """UserError unless the exported model ``path`` runs at ``resolution`` (a U-Net is built for one frame size)."""
    expected = model_info(path, option)["resolution"]
    if expected != resolution:
        raise UserError(
            f"{option} {path} runs at {expected}² but --resolution is {resolution}", f"pass --resolution {expected}"
        )


class ExportedGenerator(ABC):
    """An exported generator ready to predict GI maps; a subclass brings the backend that runs it.

    ``path`` is a ``.onnx`` file from ``gigan-export`` (``model.json`` must sit beside it); ``threads``
    sets the backend's CPU threads; ``warmup`` runs that many dummy inferences so the first real frame is
    not slowed by lazy initialisation.
    """

    #: What runs the network, e.g. "onnxruntime cpu" or "torch cuda float16" (a run's provenance).
    backend: str

    def __init__(self, path: str | Path, threads: int = 2, warmup: int = 2) -> None:
        self.path = Path(path)
        if not self.path.is_file():
            raise UserError(f"model file {self.path} is missing", "export one with `gigan-export RUN --out DIR`")
        self.config: dict[str, Any] = read_model_json(self.path)
        self.spec = InputSpec.from_dict(self.config["input"])
        self.resolution = int(self.config["resolution"])
        if threads < 1:
            raise ValueError(f"threads must be >= 1, got {threads}")
        shape = (1, self.spec.in_channels, self.resolution, self.resolution)
        self._load(threads, shape)
        # the network input, encoded in place by every predict (one model serves one caller at a time)
        self._input = self._input_array(shape)
        for _ in range(warmup):
            self._run(self._input)

    @abstractmethod
    def _load(self, threads: int, shape: tuple[int, int, int, int]) -> None:
        """Load the network for inputs of ``shape`` (1xCxHxW); a UserError naming the file if it cannot."""

    @abstractmethod
    def _run(self, x: np.ndarray) -> np.ndarray:
        """The network's output (3xHxW float32 in [-1, 1], on the host) for the input ``x`` (1xCxHxW)."""

    def _input_array(self, shape: tuple[int, ...]) -> np.ndarray:
        """The host array the frame is encoded into (a backend may place it in memory it copies from faster)."""
        return np.zeros(shape, np.float32)

    @property
    def buffers(self) -> tuple[str, ...]:
        """Buffers ``predict`` needs, in channel order."""
        return self.spec.buffers

    def predict(self, frame_buffers: dict[str, np.ndarray]) -> np.ndarray:
        """Linear GI radiance (HxWx3 float32, C-contiguous) from the frame's buffers (name -> HxWxC linear
        arrays), host copies to and from the backend's device included. Not reentrant: the buffers are encoded
        into the model's one input array."""
        self.check_frame_size(frame_buffers)
        divisor = frame_divisor(frame_buffers, self.spec)  # once, for the encoding and the decoding
        frame_to_input(frame_buffers, self.spec, out=self._input[0], divisor=divisor)
        return output_to_radiance(self._run(self._input), self.spec, divisor)

    def check_frame_size(self, frame_buffers: dict[str, np.ndarray]) -> None:
        """ValueError unless the frame's buffers are at the model's resolution."""
        sizes = {np.shape(frame_buffers[b])[:2] for b in self.spec.buffers if b in frame_buffers}
        if sizes - {(self.resolution, self.resolution)}:
            raise ValueError(
                f"frame buffers are {' and '.join(f'{h}x{w}' for h, w in sorted(sizes))} but the model runs at "
                f"{self.resolution}x{self.resolution}; render the GI-camera buffers at the model's resolution"
            )


class GIModel(ExportedGenerator):
    """The exported ONNX graph on onnxruntime's CPU provider (``threads`` intra-op threads)."""

    backend = "onnxruntime cpu"

    def _load(self, threads: int, shape: tuple[int, int, int, int]) -> None:
        import onnxruntime as ort

        options = ort.SessionOptions()
        options.intra_op_num_threads = threads
        options.inter_op_num_threads = 1
        options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        # Worker threads that spin after a run hold a core that the client's next stages (binding, the
        # warp's raster pass, the next DI render) need: on 2 cores, binding right after inference took
        # 14.8 ms with spinning and 3.9 ms without, inference itself 47 vs 30 ms (loaded machine, A/B).
        options.add_session_config_entry("session.intra_op.allow_spinning", "0")
        try:
            self.session = ort.InferenceSession(str(self.path), options, providers=["CPUExecutionProvider"])
        except Exception as e:  # onnxruntime raises its own exception types for unreadable graphs
            raise UserError(
                f"{self.path} is not a loadable ONNX model ({type(e).__name__})", "re-export it with `gigan-export`"
            ) from None

        inputs, outputs = self.session.get_inputs(), self.session.get_outputs()
        if len(inputs) != 1 or len(outputs) != 1:
            raise UserError(
                f"{self.path} has {len(inputs)} inputs and {len(outputs)} outputs, not one of each as a gigan "
                "generator",
                "re-export it with `gigan-export`",
            )
        self.input_name = inputs[0].name
        check_input_shape(self, inputs[0].shape[1:], shape)

    def _run(self, x: np.ndarray) -> np.ndarray:
        return self.session.run(None, {self.input_name: x})[0][0]


def check_input_shape(model: ExportedGenerator, file_shape: list, shape: tuple[int, ...]) -> None:
    """The graph's input (CxHxW ``file_shape``, as the ONNX file declares it) must be what ``model.json``
    describes (1xCxHxW ``shape``): a UserError naming both files otherwise."""
    if list(file_shape) != list(shape[1:]):
        raise UserError(
            f"{model.path} takes input of shape {list(file_shape)} (CxHxW) but "
            f"{model.path.parent / MODEL_JSON} describes {list(shape[1:])} "
            f"(buffers {list(model.spec.buffers)} at {model.resolution}px), so the model and its model.json "
            "do not belong together",
            "re-export with `gigan-export` so both come from one run",
        )

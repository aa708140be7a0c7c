"""`bench inference`: one GI map's inference per backend, precision and device -- error against run time.

The network input is a real frame's: the GI-camera DI + G-buffers of ``scene`` (GL where a context opens,
else Mitsuba; the run's ``input_renderer`` setting says which), encoded as the client encodes them
(:func:`gigan_local.preprocess.frame_to_input`). Each configuration runs the generator ``repeats`` times
after ``warmup`` runs; rows (``scene`` = the input's scene):

- ``system = onnxruntime``: each file of ``models`` (``precision`` from its ``model.json``) on the CPU at
  each of ``threads`` -- what the clients run;
- ``system = torch``: the generator's weights read back from ``models[0]`` (:mod:`gigan_local.warmstart`)
  on ``torch_device`` at each of ``precisions`` (fp16 and bf16 on CUDA only), ``copies = device`` (input
  on the device, output left there) and ``copies = host`` (input copied from host memory and the output
  back, as a client whose G-buffers come from a GL read-back pays). On CUDA, TF32 convolutions stay
  torch's default (on): the fp32 row's error shows what that costs.

Metrics: ``inference`` (median, p95, n in ms) and the output's ``max_abs_error`` / ``mean_abs_error``
against onnxruntime on ``models[0]`` at the first of ``threads`` (the network's raw output: log-radiance
units of :func:`gigan_local.preprocess.output_to_radiance`).
"""

from __future__ import annotations

import copy
import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bench.runner import Bench
from gicore import option_groups
from gicore.error_policy import UserError
from gicore.present.declarations import Chart, Column, Figure, Rows, Table, wide
from gicore.results import Results
from gicore.timing import time_repeats
from gigan_local.inference import DEFAULT_MODEL, ExportedGenerator, GIModel, check_model_option, model_info

#: Precisions the torch rows may run at (the ONNX rows take theirs from the model file).
TORCH_PRECISIONS = ("fp32", "fp16", "bf16")
#: Where the torch input and output live during the timed call (see the module docstring).
COPIES = ("device", "host")
#: The shipped model's fp32 file, beside its fp16 one (:data:`gigan_local.inference.DEFAULT_MODEL`).
SHIPPED_FP32 = DEFAULT_MODEL.with_name("model_fp32.onnx")


@dataclass(frozen=True)
class InferenceConfig:
    """Which model files, backends and settings to time."""

    #: Exported model files (``gigan-export``); the first is the reference of the error rows and the torch weights.
    models: tuple[Path, ...] = (SHIPPED_FP32, DEFAULT_MODEL)
    scene: str = option_groups.scene(note="its GI-camera buffers are the network input")
    #: onnxruntime intra-op threads, one row set each.
    threads: tuple[int, ...] = (1, 2)
    #: Backends: onnxruntime (CPU, as the clients) and/or torch.
    backends: tuple[str, ...] = ("onnxruntime", "torch")
    #: torch's device: auto (cuda where torch sees one, else cpu), cpu or cuda.
    torch_device: str = "auto"
    #: torch precisions (fp32, fp16, bf16); fp16 and bf16 are left out on the CPU.
    precisions: tuple[str, ...] = TORCH_PRECISIONS
    #: Timed runs per configuration.
    repeats: int = 30
    #: Untimed runs before them.
    warmup: int = field(default=5, metadata={"min": 0})

    @classmethod
    def quick(cls) -> InferenceConfig:
        return cls(models=(SHIPPED_FP32,), threads=(1,), repeats=5, warmup=2)

    def check(self) -> None:
        inputs = set()
        for path in self.models:
            doc = check_model_option(Path(path), "--models")
            inputs.add((doc["resolution"], json.dumps(doc["input"], sort_keys=True)))
        if len(inputs) > 1:
            raise UserError(
                f"--models {','.join(map(str, self.models))} take different inputs (resolution or encoding)",
                "compare models of one export or of one architecture",
            )
        for name, given, allowed in (
            ("--backends", self.backends, ("onnxruntime", "torch")),
            ("--precisions", self.precisions, TORCH_PRECISIONS),
        ):
            for value in given:
                if value not in allowed:
                    raise UserError(f"{name} {value!r} is not one of {', '.join(allowed)}", "pick some of those")
        if self.torch_device not in ("auto", "cpu", "cuda"):
            raise UserError(f"--torch-device {self.torch_device!r} is not auto, cpu or cuda", "pick one of those")


def network_input(model: ExportedGenerator, scene: str) -> tuple[np.ndarray, str]:
    """(The encoded 1xCxHxW input of ``scene``'s first GI camera at ``model``'s resolution, the renderer that
    rendered it: a model-source client's, :func:`gigan_local.client.open_renderers`)."""
    from gicore.paths import camera_path, light_position
    from gicore.scene import load_scene
    from gigan_local.client import ClientConfig, open_renderers
    from gigan_local.preprocess import frame_to_input

    spec, resolution = load_scene(scene), model.resolution
    _, raster, used = open_renderers(ClientConfig(scene=scene, resolution=resolution, gi_source="model"), spec)
    [local] = camera_path(spec, 1, seed=0, fov=spec.camera.local_fov, resolution=resolution)
    buffers = raster.render_di_gbuffers(local.with_fov(spec.camera.gi_fov), light_position(spec, 0), centre=True)
    return frame_to_input(buffers, model.spec)[None], used


def _errors(y: np.ndarray, reference: np.ndarray) -> dict[str, float]:
    diff = np.abs(np.asarray(y, np.float64) - reference)
    return {"max_abs_error": float(diff.max()), "mean_abs_error": float(diff.mean())}


def _record(res: Results, system: str, scene: str, samples: list[float], y: np.ndarray, ref: np.ndarray, **config):
    res.add_timing(system=system, scene=scene, metric="inference", samples_s=samples, **config)
    for metric, value in _errors(y, ref).items():
        res.add(system=system, scene=scene, metric=metric, value=value, unit="1", **config)


def measure(cfg: InferenceConfig, res: Results) -> None:
    reference = GIModel(cfg.models[0], cfg.threads[0], warmup=0)
    x, res.settings["input_renderer"] = network_input(reference, cfg.scene)
    ref = np.asarray(reference.session.run(None, {reference.input_name: x})[0], np.float64)
    if "onnxruntime" in cfg.backends:
        for path in cfg.models:
            precision = model_info(Path(path), "--models")["precision"]
            for threads in cfg.threads:
                model = GIModel(path, threads, warmup=0)
                samples, y = time_repeats(
                    lambda m=model: m.session.run(None, {m.input_name: x})[0], cfg.repeats, cfg.warmup
                )
                _record(res, "onnxruntime", cfg.scene, samples, y, ref, model=Path(path).name, precision=precision,
                        threads=threads, device="cpu")  # fmt: skip
    if "torch" in cfg.backends:
        measure_torch(cfg, res, x, ref)


def measure_torch(cfg: InferenceConfig, res: Results, x: np.ndarray, ref: np.ndarray) -> None:
    """The torch rows (module docstring)."""
    import torch

    from gigan_local.inference import read_model_json
    from gigan_local.torch_backend import torch_generator

    device = cfg.torch_device
    if device == "auto":
        device = "cuda" if torch.cuda.is_available() else "cpu"
    if device == "cuda" and not torch.cuda.is_available():
        raise UserError("--torch-device cuda: torch sees no CUDA device here", "use --torch-device cpu or auto")
    res.settings["torch"] = {"version": torch.__version__, "device": device} | (
        {"name": torch.cuda.get_device_name()} if device == "cuda" else {"threads": torch.get_num_threads()}
    )
    path = Path(cfg.models[0])
    generator = torch_generator(path, read_model_json(path)).to(device)

    def synced(fn: Callable[[], Any]) -> Callable[[], Any]:
        def run() -> Any:
            out = fn()
            if device == "cuda":
                torch.cuda.synchronize()
            return out

        return run

    dtypes = {"fp32": torch.float32, "fp16": torch.float16, "bf16": torch.bfloat16}
    with torch.inference_mode():
        for precision in cfg.precisions:
            if device == "cpu" and precision != "fp32":
                continue  # half-precision convolutions on the CPU are not what any client would run
            dtype = dtypes[precision]
            net = copy.deepcopy(generator).to(dtype)  # from the fp32 weights each time
            on_device = torch.from_numpy(x).to(device, dtype)
            calls = {
                "device": lambda n=net, i=on_device: n(i),
                "host": lambda n=net, d=dtype: n(torch.from_numpy(x).to(device, d)).float().cpu().numpy(),
            }
            for copies in COPIES:
                samples, y = time_repeats(synced(calls[copies]), cfg.repeats, cfg.warmup)
                y = y if isinstance(y, np.ndarray) else y.float().cpu().numpy()
                _record(res, "torch", cfg.scene, samples, y, ref, model=path.name, precision=precision, device=device,
                        copies=copies)  # fmt: skip


# -- what it shows ------------------------------------------------------------------------------------------
def configurations(rows: Rows) -> list[dict]:
    """One row per configuration, fastest first: median and p95 ms, the output's errors, its setting (onnxruntime
    threads, or where torch's input and output live) and its label."""
    keys = ("system", "model", "precision", "device", "threads", "copies")
    fields = {"median": "inference/median", "p95": "inference/p95", "max": "max_abs_error", "mean": "mean_abs_error"}
    out = [r for r in wide(rows, keys, fields) if r["median"] is not None]
    for r in out:
        r["setting"] = r["copies"] if r["threads"] is None else r["threads"]
        setting = f"copies {r['copies']}" if r["threads"] is None else f"{r['threads']} thr"
        r["label"] = f"{r['system']} {r['precision']} {r['device']} {setting}"
        r["floored"] = None if r["mean"] is None else max(r["mean"], 1e-9)
    return sorted(out, key=lambda r: r["median"])


TABLE = Table(
    configurations,
    (
        Column("backend", "{system}"),
        Column("model", "{model}"),
        Column("precision", "{precision}"),
        Column("device", "{device}"),
        Column("setting", "{setting}"),
        Column("median ms", "{median:.2f}"),
        Column("p95 ms", "{p95:.2f}"),
        Column("max abs error", "{max:.1e}"),
        Column("mean abs error", "{mean:.1e}"),
    ),
)
FIGURE = Figure(
    "inference",
    (
        Chart(
            configurations,
            "median",
            "floored",
            series="{label}",
            kind="scatter",
            xlog=True,
            ylog=True,
            xlabel="inference, median [ms]",
            ylabel="mean |output - onnxruntime fp32| (1e-9 floor)",
            title="GI-map inference: error against run time",
        ),
    ),  # fmt: skip
)


BENCH = Bench(
    "inference",
    InferenceConfig,
    measure,
    help="One GI map's inference per backend (onnxruntime threads, torch fp32/fp16/bf16 on CPU or CUDA, with and "
    "without host copies): median ms against the output's error vs onnxruntime fp32.",
    parts=(TABLE, FIGURE),
)

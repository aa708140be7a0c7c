"""Helpers of the cloud-baking tests: small sphere scenes as spec files, a server process, requests."""

from __future__ import annotations

import json
import os
import select
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

BIN = Path(sys.executable).parent
#: The test maps' size and spp: enough to exercise every stage, cheap on 2 cores.
RES, SPP = 64, 4


def write_scenes(folder: Path) -> Path:
    """``ball_moving`` (a sphere and a box in a Cornell box, light moving) and ``ball_static`` (the
    same on a white plane, static light) as JSON spec files in ``folder``; returns the folder."""
    import trimesh  # here: importing it costs every pytest worker a second at collection

    folder.mkdir(parents=True, exist_ok=True)
    trimesh.creation.icosphere(subdivisions=3).export(folder / "sphere.obj")
    base: dict[str, Any] = {
        "objects": [{"name": "ball", "mesh": "sphere.obj", "height": 1.0}],
        "camera": {"target": [0.0, 0.5, 0.0], "radius": 2.0, "height": 1.1, "azimuth_range": 70.0},
        "resolution": RES,
    }
    moving_light = {"position": [0.0, 2.2, 0.3], "intensity": 8.0, "amplitude": [0.6, 0.15]}
    moving = base | {"name": "ball_moving", "environment": "cornell_box", "light": moving_light}
    static = base | {
        "name": "ball_static",
        "environment": "white_plane",
        "light": {"position": [0.8, 2.6, 1.2], "intensity": 12.0},
    }
    for spec in (moving, static):
        (folder / f"{spec['name']}.json").write_text(json.dumps(spec))
    return folder


def gimap_body(scene: str = "ball_moving", eye=(1.6, 1.1, 1.2), **fields: Any) -> dict[str, Any]:
    """A valid GI-map request at ``RES``/``SPP`` (``fields`` override or add top-level fields)."""
    body = {
        "scene": scene,
        "camera": {"eye": list(eye), "target": [0.0, 0.5, 0.0]},
        "resolution": RES,
        "spp": SPP,
        "codec": "jpeg",
    }
    return body | fields


@contextmanager
def server_process(
    store: Path, scenes: Path, *args: str, env: dict[str, str] | None = None, timeout: float = 60.0
) -> Iterator[str]:
    """Run ``cloudbaking-server --port 0`` and yield its base URL (from its first stdout line). Its stderr goes to
    a file beside the store (a pipe nobody reads would stall a chatty server), quoted when it does not start."""
    cmd = [
        str(BIN / "cloudbaking-server"),
        "--host",
        "127.0.0.1",
        "--port",
        "0",
        "--store",
        str(store),
        "--scenes",
        str(scenes),
        *args,
    ]
    log = Path(store).parent / f"{Path(store).name}.server.stderr"
    with log.open("wb") as err:
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=err, text=True, env=os.environ | (env or {}))
    try:
        ready, _, _ = select.select([proc.stdout], [], [], timeout)
        assert ready, f"no output from cloudbaking-server within {timeout} s: {log.read_text()[-2000:]}"
        line = proc.stdout.readline()
        assert line.startswith("listening on http://127.0.0.1:"), (line, proc.poll(), log.read_text()[-2000:])
        yield line.split()[-1].strip()
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=15)


def passthrough_model(folder: Path, resolution: int = RES, albedo_floor: float | None = None) -> Path:
    """A real ONNX "generator" (one Slice node: it returns its DI input channels) with the model.json that
    ``gigan-export`` writes: onnxruntime runs it at ``resolution`` like the shipped model at 256²; albedo-demodulated
    with ``albedo_floor`` (it then returns the DI's shading, which the client multiplies back: the DI again)."""
    import onnx
    from onnx import TensorProto, helper

    from gigan_local.inference import FORMAT, MODEL_JSON
    from gigan_local.preprocess import InputSpec

    spec = InputSpec(albedo_floor=albedo_floor)
    x = helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, spec.in_channels, resolution, resolution])
    y = helper.make_tensor_value_info("y", TensorProto.FLOAT, [1, 3, resolution, resolution])
    consts = [helper.make_tensor(n, TensorProto.INT64, [1], [v]) for n, v in (("start", 0), ("end", 3), ("axis", 1))]
    graph = helper.make_graph(
        [helper.make_node("Slice", ["x", "start", "end", "axis"], ["y"])], "di_passthrough", [x], [y], consts
    )
    folder.mkdir(parents=True, exist_ok=True)
    onnx.save(
        helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)], ir_version=8), folder / "model.onnx"
    )
    doc = {
        "format": FORMAT,
        "model": "passthrough",
        "input": spec.to_dict(),
        "resolution": resolution,
        "ngf": 0,
        "files": {"fp32": "model.onnx"},
    }
    (folder / MODEL_JSON).write_text(json.dumps(doc))
    return folder / "model.onnx"

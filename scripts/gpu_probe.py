"""What a client path without host round trips would gain on this machine's GPU: the costs that decide how a GI map
should travel from the network (cloud baking) or the network's output (GIGAN) to the warp's GL texture.

    python scripts/gpu_probe.py [--out FILE.json] [--resolutions 256,512] [--repeats 30]

For each resolution, on a synthetic GI map and depth coded as a cloud-baking payload (JPEG quality 90 and the
depth codec), the median of ``--repeats`` after three warm-ups, in ms:

- ``cpu_decode``: the client's decode of the payload on the CPU (``decode_payload``);
- ``gpu_jpeg``: nvJPEG (``torchvision.io.decode_jpeg`` on CUDA) and the inverse tone map as a table on the GPU;
- ``gpu_depth``: zstandard on the CPU, the byte planes, prefix sum and float16 widening on the GPU;
- ``host_upload``: a float32 map from host memory into a GL texture (``Texture.write``), finished;
- ``interop_upload``: the same map from CUDA memory into a pixel buffer registered with CUDA
  (``cudaGraphicsGLRegisterBuffer``), then into the texture on the GPU, finished;

and the checks: the texture's contents equal by both uploads, and the GPU decode's map against the CPU's (largest
difference in 8-bit steps: nvJPEG and libjpeg may round apart). A part that cannot run here (no CUDA, no
torchvision, no EGL on the GPU, no CUDA-GL interop) is one line saying why; the others still run.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np


def timed(work: Callable[[], Any], repeats: int, sync: Callable[[], None] = lambda: None) -> float:
    """Median ms of ``work`` (``sync`` after each: the GPU's queue drained) after three untimed runs."""
    for _ in range(3):
        work()
        sync()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        work()
        sync()
        times.append((time.perf_counter() - t0) * 1e3)
    return statistics.median(times)


def payload(resolution: int) -> bytes:
    """A cloud-baking payload of a smooth synthetic map and depth at ``resolution``² (what a hit returns)."""
    from baseline_cloudbaking.codecs import CODECS, DEPTH_CODEC
    from baseline_cloudbaking.protocol import pack
    from gicore.camera import Camera

    yy, xx = np.mgrid[0:resolution, 0:resolution] / resolution
    gi = np.stack([np.sin(xx * 3) + 1.0, np.cos(yy * 2) + 1.0, xx * yy + 0.2], -1).astype(np.float32)
    depth = (1.0 + xx + yy).astype(np.float32)
    camera = Camera((1.2, 1.1, 1.5), (0.0, 0.5, 0.0), fov=90.0, width=resolution, height=resolution)
    header = {"codec": "jpeg", "camera": camera.to_dict(), "view": np.eye(4).tolist(), "proj": np.eye(4).tolist()}
    return pack(header, {"gi": CODECS["jpeg"].encode(gi), "depth": DEPTH_CODEC.encode(depth)})


def gpu_decode(data: bytes, repeats: int) -> dict[str, Any]:
    """nvJPEG and the depth planes on the GPU, against the CPU decode of the same payload."""
    import torch
    import torchvision.io
    import zstandard

    from baseline_cloudbaking.codecs import ARRAY_HEADER_BYTES
    from baseline_cloudbaking.protocol import decode_payload, unpack
    from gicore.tonemap import LINEAR_OF_U8

    _, sections = unpack(data)
    jpeg = torch.frombuffer(bytearray(sections["gi"]), dtype=torch.uint8)
    table = torch.from_numpy(LINEAR_OF_U8).cuda()
    sync = torch.cuda.synchronize

    def jpeg_on_gpu() -> torch.Tensor:
        q = torchvision.io.decode_jpeg(jpeg, device="cuda")  # 3 x H x W uint8
        return table[q.permute(1, 2, 0).long()]

    depth_bytes = bytes(sections["depth"])
    h, w = np.frombuffer(depth_bytes[:8], np.uint32)

    def depth_on_gpu() -> torch.Tensor:
        raw = zstandard.ZstdDecompressor().decompress(depth_bytes[ARRAY_HEADER_BYTES:], max_output_size=2 * h * w)
        planes = torch.frombuffer(bytearray(raw), dtype=torch.uint8).cuda().view(2, -1).int()
        delta = (planes[0] | (planes[1] << 8)).view(int(h), int(w))
        bits = torch.cumsum(delta, dim=1) & 0xFFFF  # the rows' prefix sum mod 2^16, as the CPU's uint16 cumsum
        return bits.short().view(torch.float16).float()

    cpu = decode_payload(data)
    gi, depth = jpeg_on_gpu().cpu().numpy(), depth_on_gpu().cpu().numpy()
    steps = np.abs(np.searchsorted(LINEAR_OF_U8, gi) - np.searchsorted(LINEAR_OF_U8, cpu.gi)).max()
    return {
        "cpu_decode": timed(lambda: decode_payload(data), repeats),
        "gpu_jpeg": timed(jpeg_on_gpu, repeats, sync),
        "gpu_depth": timed(depth_on_gpu, repeats, sync),
        "jpeg_steps_apart": int(steps),
        "depth_equal": bool(np.array_equal(depth, cpu.depth)),
    }


def uploads(resolution: int, repeats: int) -> dict[str, Any]:
    """A float32 map into a GL texture from host memory and from CUDA memory through a registered pixel buffer."""
    import torch
    from cuda.bindings import runtime as cudart

    from gicore.gl import gl_context

    ctx = gl_context()
    image = np.random.default_rng(0).random((resolution, resolution, 3), dtype=np.float32)
    on_gpu = torch.from_numpy(image).cuda()
    texture = ctx.texture((resolution, resolution), 3, dtype="f4")
    pbo = ctx.buffer(reserve=image.nbytes)
    err, resource = cudart.cudaGraphicsGLRegisterBuffer(pbo.glo, 0)
    if err != cudart.cudaError_t.cudaSuccess:
        raise RuntimeError(f"cudaGraphicsGLRegisterBuffer: {err}")

    def from_host() -> None:
        texture.write(image)
        ctx.finish()

    def from_cuda() -> None:
        cudart.cudaGraphicsMapResources(1, resource, 0)
        _, pointer, size = cudart.cudaGraphicsResourceGetMappedPointer(resource)
        cudart.cudaMemcpy(pointer, on_gpu.data_ptr(), image.nbytes, cudart.cudaMemcpyKind.cudaMemcpyDeviceToDevice)
        cudart.cudaGraphicsUnmapResources(1, resource, 0)
        texture.write(pbo)
        ctx.finish()

    out = {"host_upload": timed(from_host, repeats)}
    texture.write(np.zeros_like(image))
    out["interop_upload"] = timed(from_cuda, repeats)
    out["uploads_equal"] = bool(np.array_equal(np.frombuffer(texture.read(), np.float32).reshape(image.shape), image))
    out["gl_renderer"] = ctx.info["GL_RENDERER"]
    cudart.cudaGraphicsUnregisterResource(resource)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, help="write the measurements here as JSON")
    parser.add_argument("--resolutions", default="256,512", help="comma-separated map sides (default 256,512)")
    parser.add_argument("--repeats", type=int, default=30, help="timed runs per measurement (default 30)")
    args = parser.parse_args(argv)
    results: dict[str, Any] = {}
    for resolution in (int(r) for r in args.resolutions.split(",")):
        row: dict[str, Any] = {}
        for name, part in (("decode", lambda: gpu_decode(payload(resolution), args.repeats)),
                           ("upload", lambda: uploads(resolution, args.repeats))):  # fmt: skip
            try:
                row |= part()
            except Exception as exc:  # a part this machine cannot run: say why, measure the rest
                row[f"{name}_error"] = f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
        results[str(resolution)] = row
        shown = ", ".join(f"{k} {v:.3f}" if isinstance(v, float) else f"{k} {v}" for k, v in row.items())
        print(f"gpu_probe {resolution}²: {shown}", flush=True)
    if args.out:
        args.out.write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())

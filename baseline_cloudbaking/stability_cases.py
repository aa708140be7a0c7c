"""The extreme inputs cloud baking's own stages must survive, as :class:`gicore.stability.Case` lists: the
codecs (extreme, black and tiny maps, NaN, truncated bytes, depth beyond float16), the GI tree (zero tolerance,
far and near eyes, NaN viewpoints, a payload over budget) and the server's API (requests at the bounds and every
kind of invalid one, to a real server: :class:`Served`); ``bench stability`` judges them."""

from __future__ import annotations

import json
import math
import shutil
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from gicore.stability import Case, Outcome, Rejected, Scene, max_rel, with_nan

if TYPE_CHECKING:
    from baseline_cloudbaking.client import RemoteConfig


def codec_cases(s: Scene) -> list[Case]:
    from baseline_cloudbaking.codecs import CODECS, DEPTH_CODEC
    from baseline_cloudbaking.codecs import measure as measure_codec

    side = 64
    ramp = np.logspace(-30, 30, side * side * 3, dtype=np.float64).reshape(side, side, 3).astype(np.float32)
    maps = {
        "extreme HDR 1e-30 … 1e30": ramp,
        "black": np.zeros((side, side, 3), np.float32),
        "tiny values 1e-38": np.full((side, side, 3), 1e-38, np.float32),
    }
    rendered: dict[str, np.ndarray] = {}

    def round_trip(codec, image_fn: Callable[[], np.ndarray]) -> Callable[[], Outcome]:
        def run() -> Outcome:
            image = image_fn()
            report, data, decoded = measure_codec(codec, image)
            if codec.lossless:
                err = float(np.abs(decoded - codec.quantize(image)).max())
                return Outcome((decoded,), err, "max |decoded - quantized input| (lossless)", 0.0, f"{report.bytes} B")
            return Outcome((decoded,), report.rmse, "RMSE vs input (tone-mapped)", codec.max_rmse, f"{report.bytes} B")

        return run

    def rendered_map() -> np.ndarray:
        if "gi" not in rendered:
            rendered["gi"] = s.renderer.render_gt(s.gi_camera, s.light, spp=s.spp, seed=s.seed)
        return rendered["gi"]

    def corrupt(codec) -> Outcome:
        data = codec.encode(maps["black"])
        return Outcome((codec.decode(data[: len(data) // 2] + b"\x00" * 7),))

    cases = []
    for name, codec in CODECS.items():
        for label, image in maps.items():
            cases.append(Case("codecs", f"{name}: {label}", "finite", round_trip(codec, lambda im=image: im)))
        cases += [
            Case("codecs", f"{name}: rendered GI map", "finite", round_trip(codec, rendered_map)),
            Case(
                "codecs",
                f"{name}: NaN in the map",
                "rejected",
                lambda c=codec: Outcome((c.encode(with_nan(maps["black"])),)),
            ),
            Case("codecs", f"{name}: truncated bytes", "rejected", lambda c=codec: corrupt(c)),
        ]

    def depth_extremes() -> Outcome:
        depth = np.array([[0.0, 1e-4, 1.0, 1e4, 65504.0]] * 4, np.float32)
        decoded = DEPTH_CODEC.decode(DEPTH_CODEC.encode(depth))
        nz = depth > 6.1e-5  # float16's smallest normal: below it the relative bound does not hold
        err = max_rel(decoded[nz], depth[nz])
        return Outcome((decoded,), err, "max relative depth error (normal float16 range)", DEPTH_CODEC.max_rel_error)

    cases += [
        Case("codecs", "depth: 0 … 65504", "finite", depth_extremes),
        Case(
            "codecs",
            "depth: 1e5 (beyond float16)",
            "rejected",
            lambda: Outcome((DEPTH_CODEC.encode(np.full((4, 4), 1e5, np.float32)),)),
        ),
        Case("codecs", "depth: NaN", "rejected", lambda: Outcome((DEPTH_CODEC.encode(with_nan(np.ones((4, 4)))),))),
        Case(
            "codecs",
            "depth: negative",
            "rejected",
            lambda: Outcome((DEPTH_CODEC.encode(np.full((4, 4), -1.0, np.float32)),)),
        ),
    ]
    return cases


def store_cases(work: Path) -> list[Case]:
    from baseline_cloudbaking.store import GITree
    from baseline_cloudbaking.viewpoints import MapKey, Tolerance, Viewpoint

    key = MapKey("stability", None, 64, 90.0, "jpeg", 4, False)
    payload = b"GIM1" + bytes(range(256)) * 8

    @contextmanager
    def tree(name: str, **kwargs: Any) -> Iterator[GITree]:
        root = work / name
        shutil.rmtree(root, ignore_errors=True)
        with GITree(root, **kwargs) as t:
            t.register_scene("stability", "0" * 64, None)
            yield t

    def exact(eye: tuple[float, float, float], tol: Tolerance, name: str) -> Callable[[], Outcome]:
        def run() -> Outcome:
            with tree(name, tolerance=tol) as t:
                view = Viewpoint.look_at(eye, (0.0, 0.0, 0.0))
                t.insert(key, view, payload)
                hit = t.lookup(key, view)
                if hit is None or hit.payload != payload:
                    raise RuntimeError("a stored viewpoint was not found again at distance 0")
                return Outcome(
                    (hit.distance, hit.angle_deg), hit.distance + hit.angle_deg, "distance + angle of the hit", 1e-9
                )

        return run

    def over_budget() -> Outcome:
        with tree("budget", budget_bytes=1024) as t:
            if t.insert(key, Viewpoint.look_at((1.0, 1.0, 1.0), (0.0, 0.0, 0.0)), payload) is None:
                raise Rejected(
                    f"a {len(payload)}-byte payload over the 1024-byte budget is not stored (counted as rejected)"
                )
            return Outcome(note="stored beyond its budget")

    return [
        Case("store", "zero tolerance: exact hit", "finite", exact((1.0, 2.0, 3.0), Tolerance(0.0, 0.0), "zero_tol")),
        Case("store", "eye at 1e4 (the request bound)", "finite", exact((1e4, 1e4, 1e4), Tolerance(), "far")),
        Case("store", "eye at 1e-4 from the target", "finite", exact((1e-4, 0.0, 0.0), Tolerance(), "near")),
        Case(
            "store",
            "NaN viewpoint",
            "rejected",
            lambda: Outcome((Viewpoint.look_at((math.nan, 0.0, 0.0), (0.0, 0.0, 0.0)).eye,)),
        ),
        Case(
            "store",
            "eye = target",
            "rejected",
            lambda: Outcome((Viewpoint.look_at((1.0, 1.0, 1.0), (1.0, 1.0, 1.0)).eye,)),
        ),
        Case("store", "NaN tolerance", "rejected", lambda: Outcome((Tolerance(math.nan, 1.0).position,))),
        Case("store", "payload over the byte budget", "rejected", over_budget),
    ]


@dataclass(frozen=True)
class Served:
    """The real server the process cases ask, how the cloud client asks it for the GI camera's map
    (``remote``), and how long they wait."""

    remote: RemoteConfig
    case_timeout_s: float
    #: The cloud client's connect and read timeout through a dead link (twice it: its deadline).
    client_timeout_s: float

    def body(self, s: Scene) -> dict[str, Any]:
        """The cloud client's request for the map at ``s``'s GI camera."""
        return json.loads(self.remote.body(s.gi_camera, s.light))


def post(served: Served, content: bytes | str) -> Callable[[], Outcome]:
    """A case's run: ``content`` posted to the server's /v1/gimap; a 4xx is a clean refusal naming the field."""
    import httpx

    from baseline_cloudbaking.protocol import decode_payload

    def run() -> Outcome:
        r = httpx.post(f"{served.remote.server}/v1/gimap", content=content,
                       headers={"content-type": "application/json"}, timeout=served.case_timeout_s)  # fmt: skip
        if r.status_code >= 500:
            raise RuntimeError(f"HTTP {r.status_code}: {r.text[:200]}")
        if r.status_code != 200:
            detail = r.json().get("detail")
            listed = isinstance(detail, list) and detail
            where = "/".join(map(str, detail[0]["loc"])) if listed and "loc" in detail[0] else "?"
            msg = detail[0].get("msg", "") if listed else str(detail)
            raise Rejected(f"HTTP {r.status_code} at {where}: {msg}")
        payload = decode_payload(r.content)
        return Outcome((payload.gi, payload.depth), note=f"HTTP 200, {len(r.content)} B, hit={payload.hit}")

    return run


def server_cases(s: Scene, served: Served) -> list[Case]:
    """Requests straight to the server: valid ones at the bounds, and every kind of invalid one."""
    body = served.body(s)

    def ask(**changes: Any) -> Callable[[], Outcome]:
        return post(served, json.dumps(body | changes))

    def with_camera(**camera: Any) -> Callable[[], Outcome]:
        return ask(camera=body["camera"] | camera)

    far = 1e4
    cases = [
        Case("server", "valid request (control)", "finite", ask()),
        Case("server", "GI camera FOV 170°", "finite", with_camera(fov=170.0)),
        Case("server", "GI camera FOV 1°", "finite", with_camera(fov=1.0)),
        Case("server", "eye at 1e4 (the coordinate bound)", "finite", with_camera(eye=[far, far, far], fov=1.0)),
        Case("server", "malformed JSON", "rejected", post(served, b'{"scene": "x", "camera": ')),
        Case("server", "empty body", "rejected", post(served, b"")),
        Case("server", "NaN eye", "rejected", with_camera(eye=[math.nan, 1.0, 1.0])),  # json.dumps writes NaN
        Case("server", "Infinity FOV", "rejected", with_camera(fov=math.inf)),
        Case("server", "FOV 0°", "rejected", with_camera(fov=0.0)),
        Case("server", "FOV 180°", "rejected", with_camera(fov=180.0)),
        Case("server", "degenerate look-at (up ∥ view)", "rejected",
             with_camera(eye=[0.0, 3.0, 0.0], target=[0.0, 0.0, 0.0], up=[0.0, 1.0, 0.0])),
        Case("server", "eye = target", "rejected", with_camera(eye=[0.5, 0.5, 0.5], target=[0.5, 0.5, 0.5])),
        Case("server", "eye at 1e5 (beyond the bound)", "rejected", with_camera(eye=[1e5, 0.0, 0.0])),
        Case("server", "resolution not served", "rejected", ask(resolution=100)),
        Case("server", "spp above the server's maximum", "rejected", ask(spp=10**9)),
        Case("server", "unknown scene", "rejected", ask(scene="no_such_scene")),
        Case("server", "unknown field", "rejected", ask(extra=1)),
        Case("server", "1 MB body", "rejected", ask(pad="x" * 1_000_000)),
    ]  # fmt: skip
    return cases + ([touching_light_case(s, served)] if s.spec.light.moves else [])


def touching_light_case(s: Scene, served: Served) -> Case:
    """A light 1e-4 from a surface, sent to the server: baked where the scene's light can be there, otherwise
    refused, since the server only bakes lights within the range the scene's light sweeps (plus a light cell)."""
    from baseline_cloudbaking.server.service import light_bounds
    from baseline_cloudbaking.server.settings import Settings

    light = s.touching_light()
    low, high = light_bounds(s.spec, Settings.model_fields["light_cell"].default)
    inside = all(lo <= v <= hi for v, lo, hi in zip(light, low, high))
    name = "light 1e-4 from a surface" + ("" if inside else " (outside the scene's light range)")
    run = post(served, json.dumps(served.body(s) | {"light": list(light)}))
    return Case("server", name, "finite" if inside else "rejected", run)

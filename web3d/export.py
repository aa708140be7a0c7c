"""Scene assets for the Web3D viewer, from the same scene specs and GL code as the Python clients.

:func:`export_assets` writes into one folder:

- ``scene.bin``: the interleaved vertex data of :class:`gicore.gl.GLRenderer` at full detail (float32
  position, normal, albedo, material row: 10 per vertex; flat objects one vertex per corner with the face
  normal, smooth ones shared vertices with area-weighted normals), then the uint32 triangle indices, closed
  meshes first (drawn with back faces culled) and the others after; then the shadow map's casters (positions and
  indices) at GLRenderer's ``SHADOW_LOD`` (a quarter of the triangles, as the clients draw them);
- ``scene.json``: the header: byte offsets and counts, the draw ranges, the material tables (the shaders'
  ``u_materials``), the light (with the box it may move in, ``light_range``, and its rest point), the
  cameras' FOVs and clip distances, the navigable envelope (:func:`gicore.paths.navigation`), and the WebGL2
  programs of the scene's passes (:func:`web3d.shaders.scene_programs`);
- ``shaders.json``: the WebGL2 programs of the warps, the hole filling, the composition and GIGAN's encoding,
  from the sources the desktop GL passes compile (:func:`web3d.shaders.page_shaders`);
- ``path.json``: the scripted fly-through as a path file (:mod:`gicore.path_file`), the cameras the Python
  clients fly; the page computes the matrices, and asks for a light's shadow setup (:func:`shadow_setup`);
- ``model/``: the ONNX model and its ``model.json`` (input buffers, depth scale, resolution).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from gicore.geometry import scene_objects
from gicore.gl.brdf import ETA, TABLE_RES, roughplastic_tables
from gicore.gl.lod import LOD_RATIOS, mesh_levels
from gicore.gl.renderer import AREA_SAMPLES, GLRenderer, _closed
from gicore.gl.shaders import MATERIAL_VEC4S
from gicore.gl.shadow import SHADOW_LOD, Bounds, fit_shadow_views, shadow_size_for
from gicore.path_file import scripted_path, write_path_file
from gicore.paths import light_bounds, navigation
from gicore.scene import load_scene
from gigan_local.inference import DEFAULT_MODEL, read_model_json
from web3d.shaders import page_shaders, scene_programs

FORMAT = "gigan-web-assets/1"
#: Floats per vertex: position, normal, albedo, material row (GLRenderer's layout).
VERTEX_FLOATS = 10


def _column_major(m: np.ndarray) -> list[float]:
    return [float(x) for x in np.asarray(m, dtype=np.float64).T.ravel()]


def shadow_setup(bounds: list[Bounds], light: np.ndarray, size: int) -> dict[str, Any]:
    """GLRenderer's shadow views for a light at ``light`` (:func:`fit_shadow_views`), as the page reads them:
    column-major matrices, plain lists."""
    setup = fit_shadow_views(bounds, light, size)
    return setup | {"views": [_column_major(v) for v in setup["views"]], "atlas": list(setup["atlas"])}


def export_assets(
    scene: str | Path,
    out: Path,
    frames: int = 300,
    orbit_frames: int = 300,
    seed: int = 0,
    model: Path = DEFAULT_MODEL,
    shadow_size: int | None = None,
) -> dict[str, Any]:
    """Write the viewer's assets for ``scene`` into ``out`` (module docstring); returns the header."""
    spec = load_scene(scene)
    config = read_model_json(model)
    resolution = int(config["resolution"])
    shadow_size = shadow_size_for(resolution) if shadow_size is None else shadow_size
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    objects = scene_objects(spec)
    c = spec.camera

    roughness = sorted({o.roughness for o in objects if o.roughness is not None})
    rows = {r: i for i, r in enumerate(roughness)}
    table = np.zeros((max(1, len(roughness)), 4 * MATERIAL_VEC4S), dtype=np.float32)
    for r, i in rows.items():
        transmittance, internal = roughplastic_tables(r)
        table[i, :TABLE_RES], table[i, TABLE_RES], table[i, TABLE_RES + 1] = transmittance, r, 1.0 / (1 - internal)

    chunks, closed_faces, open_faces, base = [], [], [], 0
    casters, caster_faces, caster_base = [], [], 0
    for obj in objects:
        full, coarse = mesh_levels(obj.mesh, (1.0, LOD_RATIOS[SHADOW_LOD]))
        data, faces, _ = GLRenderer._vertex_data(obj, full, rows)  # the renderer's own vertex layout
        chunks.append(data)
        (closed_faces if _closed(obj.mesh) else open_faces).append(faces.astype(np.int64) + base)
        base += len(data)
        casters.append(coarse.mesh.vertices)  # the shadow map's casters at GLRenderer's SHADOW_LOD
        caster_faces.append(coarse.mesh.faces.astype(np.int64) + caster_base)
        caster_base += len(coarse.mesh.vertices)
    vertices = np.concatenate(chunks).astype(np.float32)
    empty = [np.zeros((0, 3), np.int64)]
    culled, rest = (np.concatenate(f or empty).astype(np.uint32) for f in (closed_faces, open_faces))
    indices = np.concatenate([culled, rest])
    shadow_vertices = np.concatenate(casters).astype(np.float32)
    shadow_indices = np.concatenate(caster_faces).astype(np.uint32)
    blobs = [vertices, indices, shadow_vertices, shadow_indices]
    offsets = np.cumsum([0] + [b.nbytes for b in blobs])
    (out / "scene.bin").write_bytes(b"".join(b.tobytes() for b in blobs))

    header: dict[str, Any] = {
        "format": FORMAT,
        "scene": spec.name,
        "resolution": resolution,
        "vertex_floats": VERTEX_FLOATS,
        "vertices": {"offset": 0, "count": len(vertices)},
        "indices": {"offset": int(offsets[1]), "count": int(indices.size), "culled": int(culled.size)},
        "shadow_vertices": {"offset": int(offsets[2]), "count": len(shadow_vertices)},
        "shadow_indices": {"offset": int(offsets[3]), "count": int(shadow_indices.size)},
        "shadow_lod": SHADOW_LOD,
        "triangles": int(indices.size // 3),
        "materials": [float(x) for x in table.ravel()],
        "material_vec4s": MATERIAL_VEC4S,
        "eta": ETA,
        "light": {"size": spec.light.size, "intensity": spec.light.intensity, "samples": AREA_SAMPLES},
        "light_range": [list(corner) for corner in light_bounds(spec)],
        "light_rest": [float(v) for v in spec.light.position],
        "camera": {"local_fov": c.local_fov, "gi_fov": c.gi_fov, "near": c.near, "far": c.far, "up": [0.0, 1.0, 0.0]},
        "navigation": navigation(spec),
        "shadow_size": shadow_size,
        "programs": scene_programs(spec, len(table)),
    }
    (out / "scene.json").write_text(json.dumps(header))
    (out / "shaders.json").write_text(json.dumps(page_shaders(resolution, config["input"])))
    flown = scripted_path(spec, frames, orbit_frames, seed)
    write_path_file(out / "path.json", flown.scene, flown.frames, flown.source)

    model_dir = out / "model"
    model_dir.mkdir(exist_ok=True)
    shutil.copyfile(model, model_dir / "model.onnx")
    (model_dir / "model.json").write_text(json.dumps(config))
    return header

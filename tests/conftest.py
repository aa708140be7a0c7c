"""Shared fixtures: tiny user-mesh scenes and a shared renderer.

Render tests use a small icosphere written as a user mesh (no procedural anatomy to generate) at
32-64 px and a few samples per pixel, so the whole gicore suite stays within seconds on 2 cores.
"""

from __future__ import annotations

import signal
from pathlib import Path
from typing import Any

import pytest

#: Resolution of the shared test renderer (square).
RES = 32


def pytest_configure(config: pytest.Config) -> None:
    """Let the Ctrl-C tests' subprocesses see SIGINT even when the suite itself was started with SIGINT
    ignored (as a shell starts background jobs, `nohup ... &`): an ignored signal stays ignored across
    exec, a handled one is reset to the default, which Python turns into KeyboardInterrupt."""
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Modules with a slow test first (a stable sort: modules and their tests otherwise keep their order).
    pytest-xdist hands each worker whole modules in this order (the Makefile's ``--dist loadfile
    --no-loadscope-reorder``): a long module handed out last would keep one worker busy while the others wait,
    and the short ones, last, fill the workers' ends evenly."""
    slow = {item.path for item in items if item.get_closest_marker("slow")}
    items.sort(key=lambda item: item.path not in slow)


@pytest.fixture(scope="session")
def sphere_mesh_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """An icosphere (642 vertices) stored as an OBJ user mesh."""
    import trimesh

    path = tmp_path_factory.mktemp("meshes") / "sphere.obj"
    trimesh.creation.icosphere(subdivisions=3).export(path)
    return path


@pytest.fixture(scope="session")
def box_mesh_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A box stored as a PLY user mesh."""
    import trimesh

    path = tmp_path_factory.mktemp("meshes") / "box.ply"
    trimesh.creation.box(extents=(0.6, 1.0, 0.6)).export(path)
    return path


@pytest.fixture(scope="session")
def make_spec(sphere_mesh_path: Path, box_mesh_path: Path):
    """Factory for small scene specs: a sphere (and optionally a box) on a white plane by default.

    Keyword arguments override top-level fields; ``light`` and ``camera`` dicts are merged into the
    defaults.
    """
    from gicore.scene import SceneSpec

    def factory(
        *, light: dict[str, Any] | None = None, camera: dict[str, Any] | None = None, with_box: bool = False, **top: Any
    ):
        objects = [{"name": "ball", "mesh": str(sphere_mesh_path), "height": 1.0, "position": [0.0, 0.0, 0.0]}]
        if with_box:
            objects.append(
                {
                    "name": "box",
                    "mesh": str(box_mesh_path),
                    "height": 0.8,
                    "position": [0.9, 0.0, -0.4],
                    "rotate_y": 30.0,
                }
            )
        data: dict[str, Any] = {
            "name": "test_scene",
            "objects": objects,
            "environment": "white_plane",
            "light": {"position": [0.8, 2.6, 1.2], "intensity": 12.0} | (light or {}),
            "camera": {"target": [0.0, 0.5, 0.0], "radius": 2.4, "height": 1.2} | (camera or {}),
            "resolution": RES,
        }
        data.update(top)
        return SceneSpec.from_dict(data)

    return factory


@pytest.fixture(scope="session")
def sphere_spec(make_spec):
    """Sphere and box on a white plane, static point light."""
    return make_spec(with_box=True)


@pytest.fixture(scope="session")
def renderer(sphere_spec):
    """One compiled Mitsuba scene shared by the render tests (cameras/light are passed per call)."""
    from gicore.render import Renderer

    return Renderer(sphere_spec, RES)


@pytest.fixture(scope="session")
def cornell_renderer(make_spec):
    """The sphere inside a Cornell box (strong indirect light from coloured walls)."""
    from gicore.render import Renderer

    spec = make_spec(
        environment="cornell_box",
        light={"position": [0.0, 2.2, 0.3], "intensity": 8.0},
        camera={"radius": 2.05, "height": 1.05, "target": [0.0, 0.6, 0.0], "azimuth_range": 70.0},
    )
    return Renderer(spec, RES)

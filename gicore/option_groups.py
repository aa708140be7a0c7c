"""Options many commands share, each declared once here: its flag, its limits and its help.

A config composes a shared option by declaring its field with the group's factory, giving its own default
where it differs and, where it helps, a note on what the option means in that command (appended to the help)::

    @dataclass(frozen=True)
    class LatencyConfig:
        scenes: tuple[str, ...] = scenes(one=True, note="the one both clients fly through")
        resolution: int = resolution()

The fields stay the config's own, so the command line stays flat (``--scenes``, ``--resolution``) and
:func:`gicore.options.config_dict` records them as before. Each carries ``metadata["group"]``, its group's
name, which tells a composed option from a hand-declared one. Options that are no config field, such as
``--out`` and the bench runner's ``--seed``, are command parameters made here (:func:`out`,
:func:`seed_parameter`, :func:`scenes_argument`, :func:`scene_argument`). The executor's options are one dataclass,
:class:`gicore.executor.ExecutorOptions`; the network profiles' are :func:`network_sim.profiles.profiles_field`.
"""

from __future__ import annotations

import inspect
from dataclasses import field
from pathlib import Path
from typing import Annotated, Any

import typer

from gicore.error_policy import UserError
from gicore.options import FRAMES, RESOLUTION, SEED, SPP, extra, limits_text

SCENES_HELP = "Built-in scene names or spec files"
SCENE_HELP = "The scene, a built-in name or a spec file"
RESOLUTION_HELP = "Square resolution in pixels"
SPP_HELP = "Path-tracing samples per pixel"
SEED_HELP = "Random seed"
DENOISE_HELP = "Denoise the path-traced renders with Intel OIDN (albedo and normal guided)"
EVERY_HELP = "GI-map period k: a new GI map every k frames"
ORBIT_FRAMES_HELP = "Frames per full orbit of the camera path (the motion per frame: 360° / orbit_frames)"
PATH_HELP = (
    "Path file (gigan-path/1: a recorded session, or any run's path.json) to fly in place of the scene's"
    " fly-through; it sets each frame's camera, light and the frame count (--seed still seeds the render noise)"
)
OUT_HELP = "Output folder"


def shared(group: str, default: Any, help_text: str, note: str = "", **metadata: Any) -> Any:
    """The field of shared option ``group``: ``help_text`` (with ``note`` after it) and ``metadata``."""
    return field(default=default, metadata={**metadata, "group": group, "help": with_note(help_text, note)})


def with_note(help_text: str, note: str) -> str:
    """A shared help text with what the option means in one command."""
    return f"{help_text} ({note})." if note else f"{help_text}."


def check_scene(option: str, scene: str) -> None:
    """Every scene must load before anything is measured (a typo should not cost a half-finished run)."""
    from gicore.scene import load_scene

    try:
        load_scene(scene)
    except (OSError, ValueError) as exc:
        raise UserError(
            f"{option} {scene!r}: {' '.join(str(exc).split())}", "give built-in scene names or spec files"
        ) from None


def scenes(default: tuple[str, ...] = ("lung_plane",), *, one: bool = False, note: str = "") -> Any:
    """``--scenes``: scene names or spec files, each loaded when the options are checked; ``one``: exactly one."""
    if one:
        return shared("scenes", default, SCENE_HELP, note, max_len=1, check=check_scene)
    return shared("scenes", default, SCENES_HELP, note, check=check_scene)


def scene(default: str = "lung_plane", *, note: str = "") -> Any:
    """``--scene``: the one scene of a run (name or spec file; loaded by the run)."""
    return shared("scene", default, SCENE_HELP, note)


def resolution(default: int | None = 256, *, note: str = "") -> Any:
    """``--resolution``: a square resolution within the one resolution limit."""
    return shared("resolution", default, RESOLUTION_HELP, note, **RESOLUTION)


def spp(default: int = 64, *, note: str = "") -> Any:
    """``--spp``: path-tracing samples per pixel."""
    return shared("spp", default, SPP_HELP, note, **SPP)


def seed(default: int = 0, *, note: str = "") -> Any:
    """``--seed``: what it seeds goes in the note."""
    return shared("seed", default, SEED_HELP, note, **SEED)


def denoise(default: bool = True, *, note: str = "") -> Any:
    """``--denoise/--no-denoise``: OIDN on the path-traced renders."""
    return shared("denoise", default, DENOISE_HELP, note)


def every(default: int = 30, *, note: str = "") -> Any:
    """``--every``/``-k``: the GI-map period in frames."""
    return shared("every", default, EVERY_HELP, note, aliases=("-k",), **FRAMES)


def orbit_frames(default: int = 300) -> Any:
    """``--orbit-frames``: the camera path's frames per orbit."""
    return shared("orbit_frames", default, ORBIT_FRAMES_HELP, **FRAMES)


def path() -> Any:
    """``--path FILE`` (:mod:`gicore.path_file`): it sets every frame, so the options that shape the scripted
    path conflict with it."""
    return shared("path", None, PATH_HELP, metavar="FILE", conflicts=("frames", "orbit_frames", "local_fov"))


# --- command parameters outside the config --------------------------------------------------------------------


def out(holds: str, default: Path | None = None) -> inspect.Parameter:
    """``--out DIR``, the folder a command writes (``holds``: what goes there); required without a default."""
    return extra("out", Annotated[Path, out_option(holds)], inspect.Parameter.empty if default is None else default)


def out_option(holds: str) -> Any:
    """``--out DIR`` as the ``typer.Option`` of a command's own ``out`` parameter."""
    return typer.Option("--out", help=with_note(OUT_HELP, holds))


def seed_parameter(note: str) -> inspect.Parameter:
    """``--seed`` as a command parameter (the bench runner's, recorded beside the config), default 0."""
    help_text = f"{with_note(SEED_HELP, note)} {limits_text(SEED)}"
    return extra("seed", Annotated[int, typer.Option("--seed", min=SEED["min"], max=SEED["max"], help=help_text)], 0)


def scenes_argument(note: str = ".toml or .json") -> inspect.Parameter:
    """The scenes as the command's arguments (``gicore-dataset SCENE...``), none by default."""
    return extra("scenes", Annotated[list[str], typer.Argument(help=with_note(SCENES_HELP, note))], [])


def scene_argument(note: str = "") -> inspect.Parameter:
    """The scene as the command's argument (``cloudbaking-prebake SCENE``)."""
    return extra("scene", Annotated[str, typer.Argument(help=with_note(SCENE_HELP, note))])

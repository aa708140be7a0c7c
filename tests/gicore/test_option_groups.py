"""gicore.option_groups: each shared option (scenes, resolution, spp, seed, --out, network profiles, ...) is
declared once, and every command that takes it takes that declaration (its help and limits)."""

from __future__ import annotations

import importlib
from collections.abc import Iterator
from dataclasses import dataclass, fields

import pytest
import typer

from gicore import option_groups as groups
from gicore.error_policy import UserError
from gicore.options import build_config, config_dict
from network_sim.profiles import PROFILE_HELP, PROFILES_HELP, profiles_field

#: Every console script's Typer app (pyproject's [project.scripts]).
APPS = {
    "bench": "bench.cli",
    "gicore-dataset": "gicore.dataset_cli",
    "gigan-train": "gigan_local.train_cli",
    "gigan-export": "gigan_local.export_cli",
    "gigan-client": "gigan_local.client_cli",
    "network-sim": "network_sim.cli",
    "cloudbaking-prebake": "baseline_cloudbaking.prebake_cli",
    "cloudbaking-client": "baseline_cloudbaking.client_cli",
    "gigan-web": "web3d.cli",
}  # cloudbaking-server's options are its settings, declared once in Settings (tests/baseline_cloudbaking)
#: The help each shared option starts with, by parameter name (a scenes option takes one or several scenes).
SHARED = {
    "scenes": (groups.SCENES_HELP, groups.SCENE_HELP),
    "scene": (groups.SCENE_HELP,),
    "resolution": (groups.RESOLUTION_HELP,),
    "spp": (groups.SPP_HELP,),
    "seed": (groups.SEED_HELP,),
    "denoise": (groups.DENOISE_HELP,),
    "every": (groups.EVERY_HELP,),
    "orbit_frames": (groups.ORBIT_FRAMES_HELP,),
    "path": (groups.PATH_HELP,),
    "out": (groups.OUT_HELP,),
    "profiles": (PROFILES_HELP,),
    "profile": (PROFILE_HELP,),
}


def commands() -> Iterator[tuple[str, object]]:
    """(command path, click command) of every leaf command of every console script."""
    for script, module in APPS.items():
        stack = [(script, typer.main.get_command(importlib.import_module(module).app))]
        while stack:
            path, command = stack.pop()
            subcommands = getattr(command, "commands", {})
            stack += [(f"{path} {name}", sub) for name, sub in subcommands.items()]
            if not subcommands:
                yield path, command


def test_every_command_takes_each_shared_option_from_its_one_declaration() -> None:
    seen: dict[str, int] = dict.fromkeys(SHARED, 0)
    for path, command in commands():
        for param in command.params:
            if param.name in SHARED:
                seen[param.name] += 1
                assert (param.help or "").startswith(SHARED[param.name]), (path, param.name, param.help)
    assert all(seen.values()), seen  # each group is in use
    assert seen["out"] >= 8 and seen["scenes"] >= 17 and seen["resolution"] >= 15, seen


@dataclass(frozen=True)
class Run:
    """A config composed of shared options."""

    scenes: tuple[str, ...] = groups.scenes(one=True, note="the one flown")
    resolution: int = groups.resolution(128)
    spp: int = groups.spp(16, note="of the GT")
    seed: int = groups.seed(note="the path")
    profiles: tuple[str, ...] = profiles_field(("lan",))
    orbit_frames: int = groups.orbit_frames()
    frames: int = 10
    path: str | None = groups.path()


def test_a_composed_config_is_flat_keeps_its_defaults_and_meets_the_group_limits() -> None:
    assert config_dict(Run()) == {
        "scenes": ["lung_plane"],
        "resolution": 128,
        "spp": 16,
        "seed": 0,
        "profiles": ["lan"],
        "orbit_frames": 300,
        "frames": 10,
        "path": None,
    }
    assert {f.name: f.metadata["group"] for f in fields(Run) if "group" in f.metadata} == {
        "scenes": "scenes",
        "resolution": "resolution",
        "spp": "spp",
        "seed": "seed",
        "profiles": "profiles",
        "orbit_frames": "orbit_frames",
        "path": "path",
    }
    assert fields(Run)[2].metadata["help"] == "Path-tracing samples per pixel (of the GT)."
    assert build_config(Run, {"resolution": 64, "profiles": "lan,wan"}) == Run(resolution=64, profiles=("lan", "wan"))


@pytest.mark.parametrize(
    ("given", "message"),
    [
        ({"resolution": 4}, "--resolution = 4 is below 8"),
        ({"spp": 5000}, "--spp = 5000 is above 4096"),
        ({"seed": -1}, "--seed = -1 is below 0"),
        ({"scenes": "lung_plane,vessels_plane"}, "--scenes has 2 values"),
        ({"scenes": "no_such_scene"}, "--scenes 'no_such_scene'"),
        ({"profiles": "lan,moon"}, "--profiles 'moon' is not a known profile"),
        ({"path": "p.json", "frames": 5}, "--path and --frames conflict"),
    ],
)
def test_the_group_checks_hold_in_every_config_that_composes_it(given: dict, message: str) -> None:
    with pytest.raises(UserError) as info:
        build_config(Run, given)
    assert str(info.value).startswith(message), str(info.value)

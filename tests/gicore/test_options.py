"""gicore.options: a console script's command built from its config dataclass (one declaration of each option,
its default, limits and help), and the checks on the final config."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal

import pytest
import typer
from typer.testing import CliRunner

from gicore.error_policy import UserError
from gicore.options import (
    FRAMES,
    HOST_PORT,
    RESOLUTION,
    build_config,
    check_fields,
    config_command,
    extra,
    field_docs,
    parse_options,
    split_host_port,
)


@dataclass(frozen=True)
class BaseRun:
    """Shared fields (as gicore.run_config.PathRunConfig is for both clients)."""

    #: Frames to run.
    frames: int = field(default=60, metadata=FRAMES)
    #: GI period k.
    every: int = field(default=30, metadata={"aliases": ("-k",)})


@dataclass(frozen=True)
class RunConfig(BaseRun):
    """A run's config: inherited fields, a renamed option, a choice, a list and bounded floats."""

    #: Training frames.
    n_train: int = field(default=4, metadata={"option": "train", "min": 0})
    #: Square resolution (limits by its name).
    resolution: int = 64
    #: Composition.
    composition: Literal["blend", "residual"] = "blend"
    #: Buffers.
    buffers: list[str] = field(default_factory=lambda: ["di", "albedo"])
    #: An Adam beta.
    beta: float = field(default=0.5, metadata={"min": 0.0, "max": 1.0, "max_open": True})
    #: A FOV; absent: the scene's.
    fov: float | None = None
    #: A file that must exist when given.
    model: Path | None = None

    def __post_init__(self) -> None:
        if self.n_train == 3:
            raise ValueError("n_train 3 is unlucky")

    def check(self) -> None:
        if self.model is not None and not self.model.is_file():
            raise UserError(f"--model {self.model} is not a file", "give a model file")


@dataclass(frozen=True)
class Files:
    """A config whose list is the command's argument."""

    #: Input folders.
    inputs: tuple[str, ...] = field(default=(), metadata={"argument": True, "min_len": 0})


def _app(seen: list) -> typer.Typer:
    app = typer.Typer(add_completion=False)

    def body(given: dict[str, Any], *, out: Path) -> None:
        """Run it."""
        seen.append((build_config(RunConfig, given), out))

    out = extra("out", Annotated[Path, typer.Option("--out", help="output folder")], Path("o"))
    config_command(app, RunConfig, body, extras=[out])
    return app


def test_command_options_come_from_the_fields_with_their_help_and_limits() -> None:
    seen: list = []
    params = {opt: p for p in typer.main.get_command(_app(seen)).params for opt in p.opts}
    assert {"--frames", "--every", "-k", "--train", "--resolution", "--composition", "--buffers", "--out"} <= set(
        params
    )
    assert "--n-train" not in params
    help_text = CliRunner(env={"COLUMNS": "250"}).invoke(_app(seen), ["--help"]).output
    assert "Frames to run. (default: 60) [1 to 100000]" in help_text
    assert "Square resolution (limits by its name). (default: 64) [8 to 2048]" in help_text
    assert "An Adam beta. (default: 0.5) [>= 0.0, < 1.0]" in help_text
    assert "A FOV; absent: the scene's. [> 0]" in help_text  # no "(default: none)"
    assert "GI period k. (default: 30) [> 0]" in help_text  # an inherited field's comment


def test_only_the_options_given_change_the_defaults() -> None:
    seen: list = []
    args = ["-k", "5", "--train", "0", "--buffers", "di, normal", "--composition", "residual", "--out", "x"]
    result = CliRunner().invoke(_app(seen), args)
    assert result.exit_code == 0, result.output
    cfg, out = seen[0]
    assert cfg == RunConfig(every=5, n_train=0, buffers=["di", "normal"], composition="residual") and out == Path("x")


@pytest.mark.parametrize(
    ("given", "message"),
    [
        ({"frames": 1_000_000_000_000}, "--frames = 1000000000000 is above 100000"),
        ({"frames": 0}, "--frames = 0 is below 1"),
        ({"every": 0}, "--every = 0 is not positive"),
        ({"n_train": -1}, "--train = -1 is below 0"),  # messages name the option, not the field
        ({"resolution": 4}, "--resolution = 4 is below 8"),
        ({"resolution": 4096}, "--resolution = 4096 is above 2048"),
        ({"beta": 1.0}, "--beta = 1.0 is not below 1.0"),
        ({"beta": float("nan")}, "--beta = nan is not finite"),
        ({"fov": float("inf")}, "--fov = inf is not finite"),
        ({"fov": 0.0}, "--fov = 0.0 is not positive"),
        ({"buffers": " , "}, "--buffers is empty"),
        ({"n_train": 3}, "invalid options: n_train 3 is unlucky"),  # the constructor's ValueError
        ({"model": Path("missing.onnx")}, "--model missing.onnx is not a file"),  # the check() hook
    ],
)
def test_bad_values_are_user_errors_naming_the_option(given: dict, message: str) -> None:
    with pytest.raises(UserError) as info:
        build_config(RunConfig, given)
    assert str(info.value).startswith(message), str(info.value)


@pytest.mark.parametrize(
    ("args", "line"),
    [
        (
            ["--frames", "1000000000000"],
            "error: --frames = 1000000000000 is above 100000: give --frames a value <= 100000",
        ),
        (["--beta", "inf"], "error: --beta = inf is not finite: give --beta a finite number"),
        (["--train", "3"], "error: invalid options: n_train 3 is unlucky: see 'prog --help'"),
        (["--composition", "bogus"], "error: Invalid value for '--composition'"),
    ],
)
def test_bad_input_is_one_error_line_and_exit_2_under_the_policy(
    capsys: pytest.CaptureFixture[str], args: list[str], line: str
) -> None:
    from gicore.error_policy import run

    with pytest.raises(SystemExit) as info:
        run(_app([]), args, prog_name="prog")
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln]
    assert info.value.code == 2 and len(lines) == 1 and lines[0].startswith(line), lines


def test_parse_options_checks_each_given_option_and_a_base_is_kept() -> None:
    assert parse_options(RunConfig, {"buffers": "gt", "every": 2}) == {"buffers": ["gt"], "every": 2}
    with pytest.raises(UserError, match="--every = -2 is not positive"):
        parse_options(RunConfig, {"every": -2})
    base = RunConfig(frames=7, every=3)
    assert build_config(RunConfig, {"every": 4}, base) == RunConfig(frames=7, every=4)


def test_check_fields_lets_a_config_meet_the_same_limits_when_built_in_code() -> None:
    check_fields(RunConfig())
    with pytest.raises(UserError, match="--composition 'x' is not one of blend, residual"):
        check_fields(dataclasses.replace(RunConfig(), composition="x"))  # Literal values are checked too
    with pytest.raises(UserError, match="--frames = 0"):
        check_fields(RunConfig(frames=0), ["frames"])


def test_a_list_field_can_be_the_argument() -> None:
    seen: list = []
    app = typer.Typer(add_completion=False)
    config_command(app, Files, lambda given: seen.append(build_config(Files, given)), name="files")
    assert CliRunner().invoke(app, ["a", "b"]).exit_code == 0
    assert CliRunner().invoke(app, []).exit_code == 0
    assert seen == [Files(("a", "b")), Files()]


def test_every_field_needs_help_and_extras_may_not_shadow_fields() -> None:
    undocumented = dataclasses.make_dataclass("U", [("b", int, 2)], frozen=True)
    with pytest.raises(TypeError, match="U.b has no #: comment"):
        config_command(typer.Typer(), undocumented, lambda given: None)
    with pytest.raises(TypeError, match=r"already adds \['frames'\]"):
        config_command(typer.Typer(), BaseRun, lambda given, frames: None, extras=[extra("frames", int, 1)])
    assert field_docs(RunConfig)["frames"] == "Frames to run."


def _twin_one() -> type:
    @dataclasses.dataclass
    class Twin:
        #: The first twin's field.
        x: int = 1

    return Twin


def _twin_two() -> type:
    @dataclasses.dataclass
    class Twin:
        #: The second twin's field.
        x: int = 2

    return Twin


def test_field_docs_of_two_classes_of_one_name_are_each_their_own() -> None:
    """A name that one module's source holds twice is found by the source parse, not the first match."""
    assert field_docs(_twin_one()) == {"x": "The first twin's field."}
    assert field_docs(_twin_two()) == {"x": "The second twin's field."}


def test_shared_limits() -> None:
    assert (RESOLUTION["min"], RESOLUTION["max"], FRAMES["max"]) == (8, 2048, 100_000)


@dataclass(frozen=True)
class Endpoints:
    """HOST:PORT fields, one of them required."""

    #: Where to connect.
    upstream: str | None = field(default=None, metadata={**HOST_PORT, "required": True})
    #: Where to listen.
    listen: str = field(default="127.0.0.1:0", metadata=HOST_PORT)


def _endpoints_app(seen: list) -> typer.Typer:
    app = typer.Typer(add_completion=False)
    config_command(app, Endpoints, lambda given: seen.append(build_config(Endpoints, given)), name="go")
    return app


def test_host_port_fields_and_required_options() -> None:
    seen: list = []
    result = CliRunner().invoke(_endpoints_app(seen), ["--upstream", "[::1]:80"])
    assert result.exit_code == 0, result.output
    assert seen == [Endpoints(upstream="[::1]:80")] and split_host_port("[::1]:80", "--upstream") == ("::1", 80)
    assert split_host_port("localhost:0", "--listen") == ("localhost", 0)
    missing = CliRunner().invoke(_endpoints_app(seen), ["--listen", "h:1"])
    assert missing.exit_code == 2 and "Missing option '--upstream'" in missing.output and len(seen) == 1
    help_text = CliRunner(env={"COLUMNS": "250"}).invoke(_endpoints_app(seen), ["--help"]).output
    assert "HOST:PORT" in help_text and "[required]" in help_text and "(default: 127.0.0.1:0)" in help_text
    for bad in ("localhost", ":80", "h:", "h:65536", "h:-1", "h:8o"):
        with pytest.raises(UserError, match=f"--listen '{bad}' is not HOST:PORT: give e.g. --listen 127.0.0.1:8000"):
            build_config(Endpoints, {"upstream": "h:1", "listen": bad})
    check_fields(Endpoints())  # an absent (None) address is not checked

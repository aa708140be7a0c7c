"""The error and signal policy's runner in process (:mod:`gicore.error_policy`; docs/architecture.md, Errors):
each kind of failure becomes one line and its exit status, user errors survive a process boundary whole, and a
bug or ``--debug`` keeps its traceback. Every console script under it: tests/integration/test_cli_errors.py.
"""

from __future__ import annotations

import pytest


def _failing_app(error: BaseException):
    import typer

    app = typer.Typer(add_completion=False)

    @app.command()
    def go(n: int = typer.Option(1, min=1)) -> None:
        raise error

    return app


@pytest.mark.parametrize(
    "error,status,line",
    [
        pytest.param(
            None,
            2,
            "error: Invalid value for '--n': Input should be greater than or equal to 1: see 'prog --help'",
            id="usage",
        ),
        pytest.param("user", 2, "error: scene.toml is broken: fix it", id="user-error"),
        pytest.param(
            FileNotFoundError(2, "No such file or directory", "in.npz"),
            2,
            "error: in.npz: No such file or directory: check the path and its permissions",
            id="oserror",
        ),
        pytest.param(KeyboardInterrupt(), 130, "interrupted: run it again", id="ctrl-c"),
        pytest.param("wrapped-interrupt", 130, "interrupted: run it again", id="ctrl-c-wrapped"),
    ],
)
def test_runner_turns_errors_into_one_line(capsys: pytest.CaptureFixture[str], error, status: int, line: str):
    from gicore.error_policy import UserError, run

    if error == "user":
        error = UserError("scene.toml is broken", "fix it")
    elif error == "wrapped-interrupt":
        try:
            raise RuntimeError("error while performing a custom differentiable operation") from KeyboardInterrupt()
        except RuntimeError as wrapped:
            error = wrapped
    argv = ["--n", "0"] if error is None else []
    with pytest.raises(SystemExit) as info:
        run(_failing_app(error or RuntimeError("unreached")), argv, prog_name="prog", resume="run it again")
    assert info.value.code == status
    assert [ln for ln in capsys.readouterr().err.splitlines() if ln] == [line]


def test_user_errors_cross_process_boundaries_intact():
    """gicore-dataset's render workers raise UserErrors that the parent prints: they must unpickle whole."""
    import pickle

    from gicore.error_policy import UserError
    from gicore.scene import SceneSpecError

    for error in (
        UserError("frame x.npz is corrupt", "render it again"),
        SceneSpecError("s.toml: 1 invalid field(s): name", "fix them"),
    ):
        back = pickle.loads(pickle.dumps(error))
        assert type(back) is type(error) and (back.what, back.todo, str(back)) == (error.what, error.todo, str(error))


def test_runner_keeps_bugs_and_debug_as_tracebacks():
    from gicore.error_policy import UserError, run

    with pytest.raises(ZeroDivisionError):  # a bug is not a user error
        run(_failing_app(ZeroDivisionError("bug")), [], prog_name="prog")
    with pytest.raises(UserError, match="broken"):  # --debug shows every error with its traceback
        run(_failing_app(UserError("broken", "fix it")), ["--debug"], prog_name="prog")

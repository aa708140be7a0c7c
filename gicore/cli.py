"""The one error policy of every console script (SPEC §8a), in the spirit of asv's ``UserError`` handler.

A user error (bad flag value, missing or corrupt file, refused rerun, invalid scene spec, NaN input, an
``--out`` that cannot be written) prints one line ``error: <what is wrong>: <what to do>`` and exits 2.
A traceback appears only for a bug, or for any error with ``--debug``. Ctrl-C prints how to resume and
exits 130. Every entry point is built with :func:`entry_point`; no command catches errors itself::

    app = typer.Typer()
    main = entry_point(app, resume="run the same command again; finished frames are kept")

and ``pyproject.toml`` names ``package.module:main``.
"""

from __future__ import annotations

import math
import os
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import NoReturn

import click
import typer

#: Exit status of a user error (as click's usage errors), and of an interrupt (128 + SIGINT).
EXIT_USER_ERROR = 2
EXIT_INTERRUPTED = 130


class UserError(Exception):
    """Something the user can fix: ``what`` is wrong (naming the file or field), ``todo`` says how.

    Raise it wherever the problem is found; the entry point turns it into one line and exit status 2.
    """

    def __init__(self, what: str, todo: str) -> None:
        super().__init__(f"{what}: {todo}")
        self.what = what
        self.todo = todo


def _oserror_line(exc: OSError) -> str:
    """A file-system error that names a path is the user's to fix (missing, unwritable, a file where a
    folder is wanted); say which path and what went wrong."""
    path = exc.filename if exc.filename2 is None else f"{exc.filename} -> {exc.filename2}"
    return f"{path}: {exc.strerror or exc}: check the path and its permissions"


def run(app: typer.Typer, argv: Sequence[str] | None = None, *, prog_name: str | None = None, resume: str | None = None) -> NoReturn:
    """Run a Typer app under the error policy and exit with its status."""
    args = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in args
    if debug:
        args.remove("--debug")
    prog = prog_name or Path(sys.argv[0]).name
    command = typer.main.get_command(app)
    try:
        command.main(args=args, prog_name=prog, standalone_mode=False)
    except click.exceptions.Exit as exc:
        sys.exit(exc.exit_code)
    except click.exceptions.UsageError as exc:
        if debug:
            raise
        hint = f"see '{exc.ctx.command_path if exc.ctx else prog} --help'"
        _fail(f"{exc.format_message()}: {hint}")
    except UserError as exc:
        if debug:
            raise
        _fail(str(exc))
    except OSError as exc:
        if debug or exc.filename is None:
            raise
        _fail(_oserror_line(exc))
    except (KeyboardInterrupt, click.exceptions.Abort):
        print(f"\ninterrupted: {resume or 'nothing half-written was kept; run the command again'}", file=sys.stderr)
        sys.exit(EXIT_INTERRUPTED)
    sys.exit(0)


def _fail(line: str) -> NoReturn:
    print(f"error: {' '.join(line.split())}", file=sys.stderr)
    sys.exit(EXIT_USER_ERROR)


def entry_point(app: typer.Typer, *, resume: str | None = None) -> Callable[[], NoReturn]:
    """The console-script function for ``app``; ``resume`` tells an interrupted user how to go on."""

    def main() -> NoReturn:
        run(app, resume=resume)

    return main


# --- checks shared by commands: each raises UserError naming the field --------------------------------


def require_positive(name: str, value: float) -> float:
    """``value`` must be finite and > 0 (an absent option means the default; zero never does)."""
    if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
        raise UserError(f"{name} = {value!r} is not a positive finite number", f"give {name} a value > 0")
    return value


def writable_dir(path: Path, *, name: str = "--out") -> Path:
    """Create ``path`` as a folder (with parents) or fail with one line if it is a file or unwritable."""
    if path.exists() and not path.is_dir():
        raise UserError(f"{name} {path} is a file", "give a folder path")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"{name} {path} cannot be created ({exc.strerror})", "give a writable folder") from exc
    if not os.access(path, os.W_OK | os.X_OK):
        raise UserError(f"{name} {path} is not writable", "give a writable folder")
    return path

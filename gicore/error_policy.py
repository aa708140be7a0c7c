"""The one error and signal policy of every console script (docs/architecture.md, Errors).

A user error (bad flag value, missing or corrupt file, refused rerun, invalid scene spec, NaN input, an
``--out`` that cannot be written) prints one line ``error: <what is wrong>: <what to do>`` and exits 2.
A traceback appears only for a bug, or for any error with ``--debug``.

Signals: SIGTERM (``kill``, a service manager, a batch scheduler) is handled exactly like Ctrl-C (SIGINT):
both raise :class:`KeyboardInterrupt` in the main thread, so every ``finally`` and ``with`` runs (locks
released, worker processes stopped, nothing half-written kept). Then

- a batch command (a dataset, a training, a bench, a client run) stopped before it finished prints one line
  ``interrupted: <what was kept and how to resume>`` on stderr and exits 130;
- a service (a server, a proxy, a viewer) runs its body in :func:`serving`: a requested stop is how it ends
  normally, so once its in-flight work is finished or dropped it exits 0, silently.

Every entry point is built with :func:`entry_point`; no command catches errors itself::

    app = typer.Typer()
    main = entry_point(app, resume="run the same command again; finished frames are kept")

and ``pyproject.toml`` names ``package.module:main``.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from types import FrameType
from typing import Any, NoReturn

import typer

#: Exit status of a user error (as click's usage errors) and of a batch command stopped by SIGINT or SIGTERM
#: (128 + SIGINT, what a shell reports for Ctrl-C).
EXIT_USER_ERROR = 2
EXIT_INTERRUPTED = 130


def _interrupt_on_sigterm(signum: int, frame: FrameType | None) -> None:
    signal.signal(signal.SIGTERM, signal.SIG_DFL)  # a second SIGTERM during the clean-up ends the process at once
    raise KeyboardInterrupt


def _catch_sigterm() -> Any:
    """Make SIGTERM a :class:`KeyboardInterrupt`, as Ctrl-C is (main thread only, and only where SIGTERM has
    its default action: an ignored one stays ignored); returns the handler to put back, or None if none was set."""
    if threading.current_thread() is not threading.main_thread():
        return None
    if signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL:
        return None
    return signal.signal(signal.SIGTERM, _interrupt_on_sigterm)


@contextmanager
def serving() -> Iterator[None]:
    """The body of a service: a stop requested by SIGINT or SIGTERM, which reaches it as a
    :class:`KeyboardInterrupt` (or as a signal the service re-raises after its own graceful shutdown, as
    uvicorn does), ends it normally, so the command exits 0. Clean-ups inside the body run first."""
    try:
        yield
    except KeyboardInterrupt:
        pass


class UserError(Exception):
    """Something the user can fix: ``what`` is wrong (naming the file or field), ``todo`` says how.

    Raise it wherever the problem is found; the entry point turns it into one line and exit status 2.
    Both parts are the exception's ``args``, so it pickles across worker processes intact.
    """

    def __init__(self, what: str, todo: str) -> None:
        super().__init__(what, todo)
        self.what = what
        self.todo = todo

    def __str__(self) -> str:
        return f"{self.what}: {self.todo}"


def _oserror_line(exc: OSError) -> str:
    """A file-system error that names a path is the user's to fix (missing, unwritable, a file where a
    folder is wanted); say which path and what went wrong."""
    path = exc.filename if exc.filename2 is None else f"{exc.filename} -> {exc.filename2}"
    return f"{path}: {exc.strerror or exc}: check the path and its permissions"


def run(
    app: typer.Typer, argv: Sequence[str] | None = None, *, prog_name: str | None = None, resume: str | None = None
) -> NoReturn:
    """Run a Typer app under the error policy and exit with its status.

    The command is parsed and invoked here rather than through Typer's own ``main``, which would turn
    Ctrl-C into a silent exit status and print usage errors as a multi-line box.
    """
    args = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in args
    if debug:
        args.remove("--debug")
    prog = prog_name or Path(sys.argv[0]).name
    command = typer.main.get_command(app)
    previous_sigterm = _catch_sigterm()
    try:
        with command.make_context(prog, args) as ctx:
            command.invoke(ctx)
    except typer.Exit as exc:  # --help, or a command that chose its exit status
        sys.exit(exc.exit_code)
    except typer.TyperException as exc:  # usage errors: bad or missing option values, unknown options
        if debug:
            raise
        ctx = getattr(exc, "ctx", None)
        if not exc.format_message().strip():  # no arguments at all: the help was already printed
            sys.exit(EXIT_USER_ERROR)
        message = (
            exc.format_message().replace("Value error, ", "").rstrip(".")
        )  # pydantic's prefix on a rejected choice
        _fail(f"{message}: see '{ctx.command_path if ctx else prog} --help'")
    except UserError as exc:
        if debug:
            raise
        _fail(str(exc))
    except BrokenPipeError:  # the reader of our output went away (`| head`): stop quietly, as Typer does
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        sys.exit(1)
    except OSError as exc:
        if debug or exc.filename is None:
            raise
        _fail(_oserror_line(exc))
    except (KeyboardInterrupt, typer.Abort):
        _interrupted(resume)
    except Exception as exc:
        if not debug and _interrupt_behind(exc):  # e.g. Dr.Jit wraps a Ctrl-C during a render in a RuntimeError
            _interrupted(resume)
        raise
    finally:
        if previous_sigterm is not None:
            signal.signal(signal.SIGTERM, previous_sigterm)
    sys.exit(0)


def _interrupt_behind(exc: BaseException) -> bool:
    """Whether a Ctrl-C (or SIGTERM) is among ``exc``'s causes and contexts."""
    seen: set[int] = set()
    cause: BaseException | None = exc
    while cause is not None and id(cause) not in seen:
        if isinstance(cause, KeyboardInterrupt):
            return True
        seen.add(id(cause))
        cause = cause.__cause__ or cause.__context__
    return False


def _interrupted(resume: str | None) -> NoReturn:
    print(f"\ninterrupted: {resume or 'nothing half-written was kept; run the command again'}", file=sys.stderr)
    sys.exit(EXIT_INTERRUPTED)


def _fail(line: str) -> NoReturn:
    print(f"error: {' '.join(line.split())}", file=sys.stderr)
    sys.exit(EXIT_USER_ERROR)


def entry_point(app: typer.Typer, *, resume: str | None = None) -> Callable[[], NoReturn]:
    """The console-script function for ``app``; ``resume`` tells an interrupted user how to go on."""

    def main() -> NoReturn:
        run(app, resume=resume)

    return main


# --- checks shared by commands: each raises UserError naming the field --------------------------------

#: The square resolution any run takes, in pixels: a scene's, a client's renders and GI maps, a dataset's
#: frames, a server's maps, a bench's renders (:mod:`gicore.options` makes it field metadata).
RESOLUTION_MIN, RESOLUTION_MAX = 8, 2048
#: Seeds are 32-bit (numpy's generators take no negative seed): a scene's, a run's, a server's.
SEED_MAX = 2**32 - 1


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

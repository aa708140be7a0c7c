"""The one error and signal policy of every console script (docs/architecture.md, Errors).

A user error (bad flag value, missing or corrupt file, refused rerun, invalid scene spec, NaN input, an
``--out`` that cannot be written) prints one line ``error: <what is wrong>: <what to do>`` and exits 2.
A traceback appears only for a bug, or for any error with ``--debug``.

Signals: SIGTERM (``kill``, a service manager, a batch scheduler) is handled exactly like Ctrl-C (SIGINT):
both raise :class:`KeyboardInterrupt` in the main thread, so every ``finally`` and ``with`` runs (locks
released, worker processes stopped, nothing half-written kept). Then

- a batch command (a dataset, a training, a bench, a client run) stopped before it finished prints one line
  ``interrupted: <what was kept and how to resume>`` on stderr and exits 130;
- a service (a server, a proxy, a viewer; ``entry_point(app, services=...)``): a requested stop is how it ends
  normally, so once its in-flight work is finished or dropped it exits 0, silently.

A service's console script is :func:`launch`: a stop that lands while its modules load ends it as quietly.
Every entry point is built with :func:`entry_point`; no command catches errors itself::

    app = typer.Typer()
    main = entry_point(app, resume="run the same command again; finished frames are kept")

and ``pyproject.toml`` names ``package.module:main``.
"""

from __future__ import annotations

import importlib
import os
import signal
import sys
import threading
from collections.abc import Callable, Collection, Sequence
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING, Any, NoReturn

if TYPE_CHECKING:  # imported by run(): launch() loads this module before any other of the program
    import typer

#: Exit status of a user error (as click's usage errors) and of a batch command stopped by SIGINT or SIGTERM
#: (128 + SIGINT, what a shell reports for Ctrl-C).
EXIT_USER_ERROR = 2
EXIT_INTERRUPTED = 130


#: Which of a console script's commands are services: True (all of them), False (none), or their names.
Services = bool | Collection[str]


def is_service(services: Services, args: Sequence[str]) -> bool:
    """Whether the command that ``args`` (the arguments after the script's name) runs is one of ``services``."""
    if isinstance(services, bool):
        return services
    return bool(args) and args[0] in services


def _interrupt_on_sigterm(signum: int, frame: FrameType | None) -> None:
    signal.signal(signal.SIGTERM, signal.SIG_DFL)  # a second SIGTERM during the clean-up ends the process at once
    raise KeyboardInterrupt


class _StopLoading:
    """The handler :func:`launch` installs: nothing has begun, so the process ends at once."""

    def __init__(self, service: bool) -> None:
        self.service = service

    def __call__(self, signum: int, frame: FrameType | None) -> None:
        if not self.service:
            os.write(2, b"\ninterrupted: nothing was started; run the command again\n")
        os._exit(0 if self.service else EXIT_INTERRUPTED)


def launch(module: str, services: Services) -> None:
    """A console script whose command's ``module`` is slow to import (its ``main`` an :func:`entry_point`): from
    here until :func:`run` takes the signals over, a Ctrl-C or SIGTERM (one not ignored) ends the process at once,
    as nothing has begun, a service with exit 0 and no word (as a stop once it serves), a batch command as an
    interrupted one. Raised as a KeyboardInterrupt inside an import, it would be a traceback."""
    if threading.current_thread() is threading.main_thread():
        handler = _StopLoading(is_service(services, sys.argv[1:]))
        for sig in (signal.SIGINT, signal.SIGTERM):
            if signal.getsignal(sig) in (signal.default_int_handler, signal.SIG_DFL):
                signal.signal(sig, handler)
    importlib.import_module(module).main()


def _catch_signals() -> Any:
    """Make SIGTERM a :class:`KeyboardInterrupt`, as Ctrl-C is, and Ctrl-C one again after
    :func:`launch` (main thread only, and only where SIGTERM has its default action or the loading
    one: an ignored one stays ignored); returns the SIGTERM handler to put back, or None if none was set."""
    if threading.current_thread() is not threading.main_thread():
        return None
    if isinstance(signal.getsignal(signal.SIGINT), _StopLoading):
        signal.signal(signal.SIGINT, signal.default_int_handler)
    previous = signal.getsignal(signal.SIGTERM)
    if previous is not signal.SIG_DFL and not isinstance(previous, _StopLoading):
        return None
    signal.signal(signal.SIGTERM, _interrupt_on_sigterm)
    return signal.SIG_DFL


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
    app: typer.Typer,
    argv: Sequence[str] | None = None,
    *,
    prog_name: str | None = None,
    resume: str | None = None,
    services: Services = False,
) -> NoReturn:
    """Run a Typer app under the error policy and exit with its status; a stop of one of ``services`` (see
    :data:`Services`) exits 0, silently.

    The command is parsed and invoked here rather than through Typer's own ``main``, which would turn
    Ctrl-C into a silent exit status and print usage errors as a multi-line box.
    """
    import typer

    args = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in args
    if debug:
        args.remove("--debug")
    prog = prog_name or Path(sys.argv[0]).name
    command = typer.main.get_command(app)
    previous_sigterm = _catch_signals()
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
        _stopped(resume, is_service(services, args))
    except Exception as exc:
        if not debug and _interrupt_behind(exc):  # e.g. Dr.Jit wraps a Ctrl-C during a render in a RuntimeError
            _stopped(resume, is_service(services, args))
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


def _stopped(resume: str | None, service: bool) -> NoReturn:
    """A requested stop: how a service ends normally (its clean-ups have run), a batch command's interruption."""
    if service:
        sys.exit(0)
    print(f"\ninterrupted: {resume or 'nothing half-written was kept; run the command again'}", file=sys.stderr)
    sys.exit(EXIT_INTERRUPTED)


def _fail(line: str) -> NoReturn:
    print(f"error: {' '.join(line.split())}", file=sys.stderr)
    sys.exit(EXIT_USER_ERROR)


def entry_point(app: typer.Typer, *, resume: str | None = None, services: Services = False) -> Callable[[], NoReturn]:
    """The console-script function for ``app``; ``resume`` tells an interrupted user how to go on; ``services``:
    the commands a stop ends normally (:data:`Services`)."""

    def main() -> NoReturn:
        run(app, resume=resume, services=services)

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

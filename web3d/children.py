"""``gigan-web``'s own cloud side: a ``cloudbaking-server`` per store state and a ``network-sim proxy`` per
profile in front of each, as child processes (:class:`network_sim.process.Running`: each started on port 0 and
waited for until it prints ``listening on``).

The ``given`` store (``--store``, or else an empty temporary folder: a cold store) has its server and every
profile's proxy started before the page is served. Beside a given store, the ``cold`` state is a second server
on an empty temporary folder, started with each of its proxies on the first request for it. A child that does
not start is :class:`~web3d.upstreams.Unavailable` (the command's one error line, or a 503 for a lazy one).
A child that ends while gigan-web runs (killed, crashed) is said in one stderr line and started again, a server
with the proxies in front of it, at most ``MAX_RESTARTS`` times each; then its store answers 503 with the reason.
Closing the cloud (on Ctrl-C, SIGTERM, or a start that failed) stops every child (SIGTERM, SIGKILL 10 s later),
proxies before their server, waits for a start still in progress, and then removes the temporary stores. Those
of a gigan-web killed by SIGKILL, which runs no clean-up, are removed by the next one that starts (:func:`sweep`).
"""

from __future__ import annotations

import csv
import functools
import os
import re
import shutil
import sys
import tempfile
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from contextlib import ExitStack
from pathlib import Path

from network_sim.process import Running, proxy
from web3d.upstreams import Unavailable

#: The console scripts of this environment.
BIN = Path(sys.executable).parent
#: Seconds a server may take to print ``listening on`` (it imports its renderer) and a proxy.
SERVER_START_S = 120.0
PROXY_START_S = 60.0
#: Times a child that ended is started again; past that its store answers 503 until gigan-web is restarted.
MAX_RESTARTS = 3
#: Seconds between two looks for children that ended (so that one is said and restarted without a request).
WATCH_S = 1.0


def warn(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


def url(child: Running) -> str:
    """The base URL of a started server or proxy."""
    host, port = child.addr  # the server prints a URL, the proxy HOST:PORT
    return f"{host}:{port}" if host.startswith("http") else f"http://{host}:{port}"


def sweep(folder: Path) -> None:
    """Remove the temporary stores in ``folder`` that this user's gigan-web runs made and did not remove (killed
    by SIGKILL): each folder's name holds the pid of the run that made it, which is no longer running."""
    for path in folder.glob("gigan-web-*-store-*"):
        made_by = re.fullmatch(r"gigan-web-(\d+)-\w+-store-\w+", path.name)
        if made_by is None or path.is_symlink() or not path.is_dir() or path.stat().st_uid != os.getuid():
            continue
        try:
            os.kill(int(made_by[1]), 0)
        except ProcessLookupError:  # that run ended
            shutil.rmtree(path, ignore_errors=True)
        except PermissionError:  # another user's process runs under that pid
            continue


def chunk_log(logs: Path, store: str, profile: str) -> Path:
    """The per-chunk log (``network-sim proxy --log``) of ``profile``'s proxy in front of ``store``'s server."""
    return logs / f"{store}_{profile}.csv"


def bytes_down(logs: Path, profile: str, store: str = "given") -> int:
    """The bytes ``profile``'s proxy in front of ``store``'s server sent down to the page, from its chunk log in
    ``logs`` (:func:`chunk_log`; complete once the proxy stopped)."""
    with chunk_log(logs, store, profile).open(newline="") as fh:
        return sum(int(r["bytes"]) for r in csv.DictReader(fh) if r["direction"] == "down" and r["sent_s"])


def start_server(
    store: Path, scenes: Path | None, *options: str, prefix: Sequence[str] = (), die_with_parent: bool = False
) -> Running:
    """A ``cloudbaking-server`` on an ephemeral port on ``store`` (and the scene spec folder ``scenes``), given
    ``options`` besides and started behind ``prefix`` (e.g. ``taskset -c 0``); started and listening."""
    argv = [*prefix, str(BIN / "cloudbaking-server"), "--port", "0", "--store", str(store)]
    argv += ["--scenes", str(scenes)] if scenes is not None else []
    return Running([*argv, *options], SERVER_START_S, die_with_parent)


class Stack:
    """One store state's server and its proxies, each started on its first use, once."""

    def __init__(
        self,
        name: str,
        store: Path | None,
        scenes: Path | None,
        seed: int,
        report: Callable[[str], None],
        spawner: ThreadPoolExecutor,
        logs: Path | None = None,
        warn: Callable[[str], None] = warn,
    ):
        self.name = name
        self.warn = warn
        self.logs = logs
        self.store = store  # None: an empty temporary folder, made when the server starts
        self.temporary: Path | None = None  # that folder, removed once every child has stopped
        self.scenes = scenes
        self.seed = seed
        self.report = report
        self.spawner = spawner
        self.lock = threading.Lock()
        self.children = ExitStack()
        self.server: Running | None = None
        self.proxies: dict[str, Running] = {}
        self.closed = False
        self.restarts: dict[str, int] = {}  # per child, e.g. "network-sim proxy lan"
        self.broken: str | None = None  # why this store is unavailable for good (a child ended too often)

    def url(self, profile: str) -> str:
        """The base URL of ``profile``'s proxy in front of this store's server, both started (or restarted) if
        need be."""
        with self.lock:
            if self.closed:
                raise Unavailable("the viewer's server is stopping")
            if self.broken is not None:
                raise Unavailable(self.broken)
            self._revive()
            if self.server is None:
                self.server = self._start_server()
            if profile not in self.proxies:
                self.proxies[profile] = self._start_proxy(profile)
            return url(self.proxies[profile])

    def revive(self) -> None:
        """Restart what ended, unless this store is closed or broken (:meth:`_revive`)."""
        with self.lock:
            if not self.closed and self.broken is None:
                self._revive()

    def _revive(self) -> None:
        """Restart a child that ended: the server with every proxy in front of it (they forward to its old port),
        or a proxy; each end is said once (``warn``). Unavailable past MAX_RESTARTS of one child."""
        if self.server is not None and self.server.proc.poll() is not None:
            self._ended("cloudbaking-server", self.server)
            profiles = list(self.proxies)
            for child in self.proxies.values():
                child.stop()
            self.proxies = {}
            self.server = self._start_server()
            for profile in profiles:
                self.proxies[profile] = self._start_proxy(profile)
        for profile, child in list(self.proxies.items()):
            if child.proc.poll() is not None:
                self._ended(f"network-sim proxy {profile}", child)
                self.proxies[profile] = self._start_proxy(profile)

    def _ended(self, what: str, child: Running) -> None:
        """Say that ``what`` ended; past MAX_RESTARTS the store is broken (Unavailable, for every request)."""
        count = self.restarts[what] = self.restarts.get(what, 0) + 1
        line = f"gigan-web: {what} of the {self.name} store (pid {child.proc.pid}) ended (exit status "
        line += f"{child.proc.returncode})"
        if count > MAX_RESTARTS:
            self.broken = f"{what} of the {self.name} store ended {count} times; restart gigan-web"
            self.warn(f"{line}, {count} times: restart gigan-web")
            raise Unavailable(self.broken)
        self.warn(f"{line}; starting it again ({count} of {MAX_RESTARTS})")

    def _start_server(self) -> Running:
        if self.store is None:
            self.store = self.temporary = Path(tempfile.mkdtemp(prefix=f"gigan-web-{os.getpid()}-{self.name}-store-"))
        start = functools.partial(start_server, self.store, self.scenes, die_with_parent=True)
        server = self._start(start, "cloudbaking-server")
        self.report(f"cloudbaking-server, {self.name} store {self.store}: {url(server)} (pid {server.proc.pid})")
        return server

    def _start_proxy(self, profile: str) -> Running:
        assert self.server is not None
        host, port = self.server.addr
        upstream = (host.removeprefix("http://"), port)
        args = ("--profile", profile, "--seed", str(self.seed))
        if self.logs is not None:  # what the proxy carried, chunk by chunk (written out as it stops)
            args += ("--log", str(chunk_log(self.logs, self.name, profile)))
        start = functools.partial(proxy, upstream, *args, timeout=PROXY_START_S, die_with_parent=True)
        child = self._start(start, f"network-sim proxy {profile}")
        self.report(f"network-sim proxy {profile} -> {self.name} store: {url(child)} (pid {child.proc.pid})")
        return child

    def _start(self, start: Callable[[], Running], what: str) -> Running:
        """Start a child on the spawner thread: it outlives every child, which gets SIGTERM from the kernel when
        that thread ends, so not even a SIGKILL of ``gigan-web`` leaves one behind."""

        def spawn() -> Running:
            child = start()
            if self.closed:  # closed while it started (Ctrl-C reaches the main thread, not this one)
                child.stop()
                raise Unavailable("the viewer's server is stopping")
            return self.children.enter_context(child)

        future = self.spawner.submit(spawn)
        try:
            return future.result()
        except (RuntimeError, TimeoutError) as exc:  # it printed no 'listening on' line; Running stopped it
            if not future.done() or future.exception() is not exc:
                # Ctrl-C landed in the wait, whose lock clean-up raised over it: a stop, not the child's failure
                raise KeyboardInterrupt from exc
            last = str(exc).strip().splitlines()[-1]
            raise Unavailable(f"{what} did not start ({last})") from None

    def state(self, child: Running | None) -> str:
        if child is None:
            return "idle"
        return "up" if child.proc.poll() is None and self.broken is None else "down"

    def close(self) -> None:
        """Stop the children, proxies first. A start in progress when the caller was interrupted is stopped by
        the spawner once it has started (``closed``); :meth:`ChildCloud.close` waits for it."""
        self.closed = True
        with self.lock:
            self.children.close()


class ChildCloud:
    """The cloud side as ``gigan-web`` starts it (module docstring): ``profiles`` (network-sim profile names; the
    first is the page's default) in front of the ``given`` store's server (``store``, else a cold temporary
    one) and, beside a given store, a lazily started ``cold`` one. ``scenes``: the folder of a scene spec file
    the servers are given. ``report`` receives one line per child started. ``logs``: a folder where each proxy
    writes its per-chunk log (:func:`chunk_log`, :func:`bytes_down`). Use as a context manager: entering starts
    the given store's children, leaving stops them all."""

    def __init__(
        self,
        profiles: tuple[str, ...],
        store: Path | None = None,
        scenes: Path | None = None,
        seed: int = 0,
        report: Callable[[str], None] = print,
        logs: Path | None = None,
        warn: Callable[[str], None] = warn,
    ) -> None:
        self._profiles = profiles
        self._spawner = ThreadPoolExecutor(1, thread_name_prefix="gigan-web-children")
        # its thread started now, before any child: a stop landing in the submit that starts it left a thread that
        # shutdown() does not wait for, whose server then made its temporary store again after the removal
        self._spawner.submit(int).result()
        self._stacks = {"given": Stack("given", store, scenes, seed, report, self._spawner, logs, warn)}
        if store is not None:
            self._stacks["cold"] = Stack("cold", None, scenes, seed, report, self._spawner, logs, warn)
        self._closing = threading.Event()

    @property
    def profiles(self) -> tuple[str, ...]:
        return self._profiles

    @property
    def stores(self) -> tuple[str, ...]:
        return tuple(self._stacks)

    def upstream(self, profile: str, store: str) -> str:
        return self._stacks[store].url(profile)

    def status(self) -> dict[str, dict[str, str]]:
        given = self._stacks["given"]
        return {
            "profiles": {p: given.state(given.proxies.get(p)) for p in self._profiles},
            "stores": {name: stack.state(stack.server) for name, stack in self._stacks.items()},
        }

    def start(self) -> None:
        """Remove what runs that were killed left (:func:`sweep`), then start the given store's server and every
        profile's proxy."""
        sweep(Path(tempfile.gettempdir()))
        for profile in self._profiles:
            self._stacks["given"].url(profile)

    def watch(self) -> None:
        """Until closed, restart the children that ended (Stack.revive), so that an end is said when it happens."""
        while not self._closing.wait(WATCH_S):
            for stack in self._stacks.values():
                try:
                    stack.revive()
                except Unavailable:  # said by the stack; its requests get it as their 503
                    continue

    def close(self) -> None:
        self._closing.set()
        for stack in self._stacks.values():
            stack.close()
        self._spawner.shutdown(wait=True)  # a start in flight finishes, sees ``closed`` and stops its child
        for stack in self._stacks.values():
            stack.close()  # again: a start that saw ``closed`` unset just before may have added its child since
            if stack.temporary is not None:  # now: a server still starting would make its folder again
                shutil.rmtree(stack.temporary, ignore_errors=True)

    def __enter__(self) -> ChildCloud:
        try:
            self.start()
        except BaseException:  # a failed start, Ctrl-C or SIGTERM: nothing is left running
            self.close()
            raise
        threading.Thread(target=self.watch, name="gigan-web-watch", daemon=True).start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

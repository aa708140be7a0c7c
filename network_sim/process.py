"""Start a server-like process and wait for its ``listening on HOST:PORT`` line (tests, self-test, benches)."""

from __future__ import annotations

import ctypes
import functools
import os
import select
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from types import TracebackType

LISTENING = "listening on "
#: prctl(2)'s option that signals a process when the thread that started it ends (Linux).
PR_SET_PDEATHSIG = 1
_PRCTL = ctypes.CDLL(None, use_errno=True).prctl if sys.platform == "linux" else None


def _die_with(parent: int) -> None:
    """In the child between fork and exec: SIGTERM when the starting thread ends (even by SIGKILL), and no start
    at all when the parent is already gone. Only a prebuilt ctypes call: nothing here takes a lock."""
    if _PRCTL is not None:
        _PRCTL(PR_SET_PDEATHSIG, signal.SIGTERM)
    if os.getppid() != parent:
        os._exit(1)


class Running:
    """A started process, the address it listens on, and its remaining stdout lines.

    ``die_with_parent`` (Linux): the child gets SIGTERM when the thread that started it ends, even when this
    process is killed with SIGKILL and runs no cleanup; start it from a thread that lives as long as the child
    should (the main thread, or a dedicated one)."""

    def __init__(self, argv: Sequence[str], timeout: float = 30.0, die_with_parent: bool = False) -> None:
        self._stderr = tempfile.TemporaryFile()
        guard = functools.partial(_die_with, os.getpid()) if die_with_parent else None
        self.proc = subprocess.Popen(list(argv), stdout=subprocess.PIPE, stderr=self._stderr, preexec_fn=guard)
        self._buffer = b""
        try:
            first = self.readline(timeout)
        except BaseException:  # a timeout, Ctrl-C or SIGTERM while it starts: no child is left running
            self.stop()
            self._stderr.close()
            raise
        if not first.startswith(LISTENING):
            why = f"{' '.join(argv)} did not start: {first!r}; stderr: {self.stderr()}"
            self.stop()
            self._stderr.close()
            raise RuntimeError(why)
        host, _, port = first[len(LISTENING) :].strip().rpartition(":")
        self.addr = (host, int(port))

    def readline(self, timeout: float) -> str:
        """The next stdout line ('' if the process ended first); raises TimeoutError after ``timeout`` s."""
        assert self.proc.stdout is not None
        fd = self.proc.stdout.fileno()
        deadline = time.monotonic() + timeout
        while b"\n" not in self._buffer:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError(f"no line from {self.proc.args} within {timeout} s; stderr: {self.stderr()}")
            if select.select([fd], [], [], left)[0]:
                data = os.read(fd, 65536)
                if not data:
                    line, self._buffer = self._buffer, b""
                    return line.decode()
                self._buffer += data
        line, _, self._buffer = self._buffer.partition(b"\n")
        return line.decode()

    def stderr(self) -> str:
        self._stderr.seek(0)
        return self._stderr.read().decode(errors="replace")

    def stop(self, timeout: float = 10.0) -> int:
        """SIGTERM, wait up to ``timeout`` s (then SIGKILL); returns the exit status."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        if self.proc.stdout is not None:
            self.proc.stdout.close()
        return self.proc.returncode

    def __enter__(self) -> Running:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.stop()
        self._stderr.close()


def network_sim(
    *args: str, timeout: float = 30.0, die_with_parent: bool = False, prefix: Sequence[str] = ()
) -> Running:
    """``network-sim ARGS...`` with this interpreter behind ``prefix`` (e.g. ``taskset -c 0``), started and
    listening."""
    return Running([*prefix, sys.executable, "-m", "network_sim", *args], timeout, die_with_parent)


def proxy(
    upstream: tuple[str, int],
    *args: str,
    timeout: float = 30.0,
    die_with_parent: bool = False,
    prefix: Sequence[str] = (),
) -> Running:
    """``network-sim proxy --upstream HOST:PORT ARGS...`` as :func:`network_sim` starts it, its clock-origin line
    read."""
    host, port = upstream
    running = network_sim("proxy", "--upstream", f"{host}:{port}", *args, timeout=timeout,
                          die_with_parent=die_with_parent, prefix=prefix)  # fmt: skip
    running.readline(timeout)
    return running

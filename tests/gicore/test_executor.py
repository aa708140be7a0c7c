"""The local render pool's process lifetime: its workers die with the driver however the
driver ends (kill -9 included: PR_SET_PDEATHSIG, and a watchdog thread where that is missing or came
too late), and a driver that stops by an exception kills its running workers instead of waiting."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from contextlib import suppress
from pathlib import Path

import pytest

from gicore.executor import LocalPool, Task

ROOT = Path(__file__).resolve().parents[2]
#: A worker or a driver still running this long past its end is a leak: half the 60 s its job sleeps, so it can
#: only be gone by then if it was ended (a slow machine takes longer to reap it, never that long).
GONE_S = 30.0
needs_proc = pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads process states from /proc")


def _nothing() -> None:
    return None


def _report_and_sleep(_: None, seconds: float) -> int:
    """A job that says which worker runs it (on the driver's stdout, inherited), then sleeps. One write of a whole
    line: the workers share the pipe, and a print's text and newline can reach it as two writes, interleaved."""
    os.write(sys.stdout.fileno(), f"busy {os.getpid()}\n".encode())
    time.sleep(seconds)
    return os.getpid()


#: A driver with a pool of two workers, each sleeping in a job.
DRIVER = """
from gicore.executor import LocalPool, Task
from tests.gicore.test_executor import _nothing, _report_and_sleep
with LocalPool(2) as pool:
    pool.run(Task(_nothing, (), _report_and_sleep), [60.0] * 4, lambda job, result: None)
"""

#: A process that starts a child watching it (the watchdog alone: no prctl), prints the child's PID, sleeps.
WATCHED = """
import subprocess, sys, time
code = "import os, threading, time; from gicore.executor import _watch_parent; "
code += "threading.Thread(target=_watch_parent, args=(os.getppid(),), daemon=True).start(); "
code += "print('watching', flush=True); time.sleep(60)"
child = subprocess.Popen([sys.executable, "-c", code])
print(child.pid, flush=True)
time.sleep(60)
"""


def alive(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie, dead but not yet reaped by its new parent, does not)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError):
        return False
    return state not in ("Z", "X")


def wait_gone(pids: list[int], limit_s: float = GONE_S) -> float:
    """Seconds until none of ``pids`` runs; fails past ``limit_s``."""
    start = time.monotonic()
    while any(alive(pid) for pid in pids):
        assert time.monotonic() - start < limit_s, f"still running after {limit_s} s: {[p for p in pids if alive(p)]}"
        time.sleep(0.005)
    return time.monotonic() - start


def kill_leftovers(pids: list[int]) -> None:
    """Kill what a failed test left running (never needed when the tests pass)."""
    for pid in pids:
        if alive(pid):
            with suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)


def read_lines(proc: subprocess.Popen, n: int, timeout_s: float = 60.0) -> list[str]:
    lines: list[str] = []
    deadline = time.monotonic() + timeout_s
    while len(lines) < n:
        assert time.monotonic() < deadline and proc.poll() is None, (lines, proc.poll())
        lines.append(proc.stdout.readline().strip())
    return lines


@needs_proc
def test_pool_workers_die_at_once_with_a_killed_driver() -> None:
    driver = subprocess.Popen(
        [sys.executable, "-c", DRIVER], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True
    )
    workers: list[int] = []
    try:
        workers += [int(line.split()[1]) for line in read_lines(driver, 2)]
        assert len(set(workers)) == 2 and all(alive(pid) for pid in workers)
        driver.kill()
        driver.wait(timeout=60)
        took = wait_gone(workers)
        print(f"pool workers gone {took * 1e3:.0f} ms after kill -9 of the driver")
    finally:
        kill_leftovers(workers)
        driver.kill()
        driver.wait()
        driver.stdout.close()


@needs_proc
def test_the_watchdog_alone_ends_a_worker_whose_parent_died() -> None:
    """Where prctl is missing, the watchdog thread sees the re-parenting within its poll."""
    parent = subprocess.Popen(
        [sys.executable, "-c", WATCHED], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True
    )
    children: list[int] = []
    try:
        pid_line, watching = read_lines(parent, 2)
        children.append(int(pid_line))
        assert watching == "watching" and alive(children[0])
        parent.kill()
        parent.wait(timeout=60)
        wait_gone(children)
    finally:
        kill_leftovers(children)
        parent.kill()
        parent.wait()
        parent.stdout.close()


def test_a_worker_whose_driver_died_before_its_initializer_exits() -> None:
    """The race prctl cannot cover: the driver died before the worker asked for its death signal."""
    code = "import time; from gicore.executor import _init_worker; _init_worker(-1); time.sleep(300)"
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, timeout=120, check=False)
    assert proc.returncode == 1, proc.stderr  # exited in the initializer: it never reached the sleep


@needs_proc
def test_an_exception_in_the_driver_kills_the_running_workers_at_once() -> None:
    workers: list[int] = []

    stopped: list[float] = []

    def stop(job: float, result: int) -> None:
        workers.extend(pool._pool._processes)  # every worker started so far
        stopped.append(time.monotonic())
        raise RuntimeError("stop")

    try:
        with pytest.raises(RuntimeError, match="stop"), LocalPool(2) as pool:
            pool.run(Task(_nothing, (), _report_and_sleep), [0.0, 60.0, 60.0, 60.0], stop)
        assert time.monotonic() - stopped[0] < GONE_S  # the 60 s jobs were ended, not waited for
        assert len(workers) == 2 and not any(alive(pid) for pid in workers)
    finally:
        kill_leftovers(workers)

"""The render executor: where the embarrassingly parallel render jobs of a run execute
(docs/architecture.md, Render executor).

A run (the frames of a data set, the maps of a prebake) is a :class:`Task` (how a worker builds its state
once, and turns one job into a result) and a list of jobs. Every backend runs the same :func:`run_job`;
results come back to the driver in completion order and the driver writes them, so a worker that dies mid-job
leaves no file. Each worker keeps the state of its last :data:`CACHED_STATES` tasks. Backends
(:func:`open_executor`): :class:`InProcess`, :class:`LocalPool` (spawned workers that die with the driver,
``kill -9`` included) and :class:`RayExecutor` (Ray tasks owned by the driver; a local instance it started
ends with it). :class:`ExecutorOptions` is the command-line form (``--executor``, ``--ray-address``,
``--workers``).
"""

from __future__ import annotations

import ctypes
import hashlib
import logging
import multiprocessing
import os
import pickle
import signal
import socket
import subprocess
import sys
import threading
import time
from collections import Counter, OrderedDict
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from contextlib import AbstractContextManager, contextmanager, suppress
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, Protocol

from gicore.error_policy import UserError
from gicore.options import THREADS

#: Task states a worker process keeps (least recently used dropped first): a run's scene, plus one
#: more so that two drivers sharing a Ray cluster do not rebuild each other's scenes on every job.
CACHED_STATES = 2
#: Seconds to wait for a Ray head's port before calling it unreachable (ray.init itself retries for minutes).
RAY_CONNECT_TIMEOUT_S = 5.0
#: How often the driver wakes from waiting on Ray, so that Ctrl-C is handled promptly.
RAY_POLL_S = 0.2
#: How long an interrupted run keeps cancelling its outstanding Ray tasks until they have all ended (s): on a busy
#: machine Ray can take many seconds to hand a task to a worker, and a cancel sent meanwhile is lost.
RAY_CANCEL_S = 30.0
#: How often a pool worker's watchdog checks that the driver that started it is still its parent (s).
PARENT_POLL_S = 0.5
#: How long an ending pool waits for its killed workers and its manager thread (s).
POOL_KILL_WAIT_S = 10.0
#: How often the watchdog of a Ray instance this driver started lists the instance's processes (s).
RAY_WATCH_S = 0.5
#: ``prctl`` option: the signal the kernel sends this process when the thread that forked it ends.
PR_SET_PDEATHSIG = 1
#: The option that names a Ray cluster's address (:class:`ExecutorOptions`), as errors name it.
RAY_OPTION = "--ray-address"
START_RAY = "start one with `ray start --head` and give its address, or use --ray-address auto"
INSTALL_RAY = "install it with pip install '.[ray]' (or leave out --executor ray to use local processes)"
#: Ray's setting for its workers' niceness (Ray's default: 15, below everything else on the machine).
RAY_WORKER_NICENESS = "RAY_worker_niceness"


@dataclass(frozen=True)
class Task:
    """What every job of a run needs. ``build(*args)`` makes a worker's state (e.g. a Renderer of the
    scene); ``work(state, job)`` returns one job's picklable result. Both must be module-level functions
    (workers import them by name) and ``args`` picklable; ``key`` identifies the state by value."""

    build: Callable[..., Any]
    args: tuple
    work: Callable[[Any, Any], Any]
    key: str = field(init=False)

    def __post_init__(self) -> None:
        ident = (self.build.__module__, self.build.__qualname__, self.args)
        object.__setattr__(self, "key", hashlib.sha256(pickle.dumps(ident)).hexdigest())


_states: OrderedDict[str, Any] = OrderedDict()
_threads: int | None = None


def run_job(task: Task, threads: int, job: Any) -> Any:
    """One job in a worker process (any backend): the process's renderer threads set to ``threads``,
    the task's state built once per process, then ``task.work(state, job)``."""
    global _threads
    if threads != _threads:
        from gicore.render import set_render_threads  # Mitsuba loads only in processes that render

        set_render_threads(threads)
        _threads = threads
    if task.key not in _states:
        _states[task.key] = task.build(*task.args)
        while len(_states) > CACHED_STATES:
            _states.popitem(last=False)
    _states.move_to_end(task.key)
    return task.work(_states[task.key], job)


#: What the driver does with each finished job: ``receive(job, result)``, in completion order.
Receive = Callable[[Any, Any], None]


class Executor(Protocol):
    """Runs a task's jobs; ``workers`` is how many run at once (None: as many as a Ray cluster has CPUs)."""

    workers: int | None

    def run(self, task: Task, jobs: Sequence[Any], receive: Receive) -> None:
        """Run every job and hand each result to ``receive`` in this process as it finishes. An
        exception (a failed job, one raised by ``receive``, Ctrl-C) cancels the jobs not yet finished
        before it propagates."""
        ...


@dataclass
class InProcess:
    """Jobs run one after another in this process, on ``threads`` renderer threads."""

    threads: int = field(default_factory=lambda: os.cpu_count() or 1)
    workers: int = 1

    def run(self, task: Task, jobs: Sequence[Any], receive: Receive) -> None:
        for job in jobs:
            receive(job, run_job(task, self.threads, job))


def _set_parent_death_signal(sig: int) -> bool:
    """Ask Linux to send ``sig`` to this process when its parent (the thread that started it) ends;
    False where that is not available."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(PR_SET_PDEATHSIG, ctypes.c_ulong(sig), 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def _watch_parent(parent: int) -> None:
    """Exit this process as soon as ``parent`` is no longer its parent (it died: we were re-parented)."""
    while os.getppid() == parent:
        time.sleep(PARENT_POLL_S)
    os._exit(1)


def _init_worker(parent: int) -> None:
    """A pool worker leaves Ctrl-C to the driver (``parent``), which stops the run, and dies with it:
    SIGKILL from the kernel when the driver ends (Linux, ``PR_SET_PDEATHSIG``), and everywhere a watchdog
    thread that exits when the parent changes (it also covers a driver that died before the prctl)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _set_parent_death_signal(signal.SIGKILL)
    if os.getppid() != parent:
        os._exit(1)
    threading.Thread(target=_watch_parent, args=(parent,), name="watch-driver", daemon=True).start()


class LocalPool:
    """``workers`` spawned processes on ``threads`` renderer threads each (default: the cores shared
    out); one pool serves every run of the executor's life (use it as a context manager). Leaving it
    normally waits for the workers to exit; leaving it by an exception kills them (:meth:`kill`).
    Use it from the thread that made it, and let that thread outlive it (every command uses its main
    thread): on Linux a worker gets SIGKILL when the thread that started it ends."""

    def __init__(self, workers: int, threads: int | None = None):
        self.workers = workers
        self.threads = threads or max(1, (os.cpu_count() or 1) // workers)
        self._pool = ProcessPoolExecutor(
            workers,
            mp_context=multiprocessing.get_context("spawn"),
            initializer=_init_worker,
            initargs=(os.getpid(),),
        )

    def __enter__(self) -> LocalPool:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, *exc: object) -> None:
        if exc_type is None:
            self._pool.shutdown(wait=True, cancel_futures=True)
        else:
            self.kill()

    def kill(self) -> None:
        """End the pool now: drop the queued jobs and SIGKILL the workers (a worker writes nothing, so
        a job cut short loses only its own result), then wait for them and for the pool's manager thread."""
        processes = list((getattr(self._pool, "_processes", None) or {}).values())
        manager = getattr(self._pool, "_executor_manager_thread", None)
        for process in processes:
            process.kill()
        self._pool.shutdown(wait=False, cancel_futures=True)
        deadline = time.monotonic() + POOL_KILL_WAIT_S
        for process in processes:
            process.join(max(0.0, deadline - time.monotonic()))
        if manager is not None:
            manager.join(max(0.0, deadline - time.monotonic()))

    def run(self, task: Task, jobs: Sequence[Any], receive: Receive) -> None:
        pending: dict[Future, Any] = {self._pool.submit(run_job, task, self.threads, job): job for job in jobs}
        try:
            while pending:
                done, _ = wait(pending, return_when=FIRST_COMPLETED)
                for future in done:
                    receive(pending.pop(future), future.result())
        finally:
            for future in pending:  # queued ones are dropped; running ones finish and are discarded
                future.cancel()


def run_ray_job(task: Task, threads: int, job: Any) -> tuple[str, Any]:
    """:func:`run_job` as a Ray task: (id of the node it ran on, the job's result)."""
    import ray

    return ray.get_runtime_context().get_node_id(), run_job(task, threads, job)


class RayExecutor:
    """Jobs as Ray tasks of ``threads`` CPUs each, at most ``workers`` in flight (None: all submitted at
    once, and the cluster runs as many as it has CPUs). Needs Ray connected (:func:`connect_ray`)."""

    def __init__(
        self,
        workers: int | None = None,
        threads: int = 1,
        max_retries: int = 3,
        placed: Callable[[Any, str], None] | None = None,
    ):
        import ray

        self.workers = workers
        self.threads = threads
        #: Jobs each Ray node (by node id) ran, over this executor's life.
        self.nodes: Counter[str] = Counter()
        #: Called with each finished job and the id of the node that ran it, before ``receive``.
        self.placed = placed
        # A worker that dies (killed, out of memory, node lost) is a system failure: Ray reruns its task.
        # An exception raised by the job itself is not retried: it is a bug or a user error to report.
        self._remote = ray.remote(run_ray_job).options(
            num_cpus=threads, max_retries=max_retries, retry_exceptions=False
        )

    def run(self, task: Task, jobs: Sequence[Any], receive: Receive) -> None:
        import ray

        task_ref = ray.put(task)  # shipped once, not with every job
        queue = list(reversed(jobs))
        pending: dict[Any, Any] = {}
        try:
            while queue or pending:
                while queue and (self.workers is None or len(pending) < self.workers):
                    job = queue.pop()
                    pending[self._remote.remote(task_ref, self.threads, job)] = job
                done, _ = ray.wait(list(pending), num_returns=1, timeout=RAY_POLL_S)
                for ref in done:
                    job = pending.pop(ref)
                    try:
                        node, result = ray.get(ref)
                    except ray.exceptions.RayTaskError as exc:
                        if isinstance(exc.cause, UserError):  # one line, as if raised here
                            raise exc.cause from None
                        raise
                    self.nodes[node] += 1
                    if self.placed is not None:
                        self.placed(job, node)
                    receive(job, result)
        finally:
            _cancel(list(pending))


def _cancel(refs: list[Any], deadline_s: float = RAY_CANCEL_S) -> None:
    """Force-cancel Ray tasks (stop a discarded render now rather than let it finish), repeating the
    cancel until every task has ended or ``deadline_s`` passed: a cancel that reaches a task while Ray is
    handing it to a worker can be lost, and the task would then run to its end (seen with Ray 2.60)."""
    import ray

    deadline = time.monotonic() + deadline_s
    while refs:
        for ref in refs:
            ray.cancel(ref, force=True)
        if time.monotonic() > deadline:
            return
        _, refs = ray.wait(refs, num_returns=len(refs), timeout=RAY_POLL_S)


def _host_port(text: str) -> tuple[str, int] | None:
    """(host, port) of a HOST:PORT address, else None."""
    host, _, port = text.rpartition(":")
    return (host.strip("[]"), int(port)) if host and port.isdigit() and 0 < int(port) < 65536 else None


def _check_reachable(address: str, option: str) -> None:
    """Fail fast on a head that does not answer: ``ray.init`` would retry for minutes."""
    try:
        socket.create_connection(_host_port(address), timeout=RAY_CONNECT_TIMEOUT_S).close()
    except OSError as exc:
        reason = exc.strerror or type(exc).__name__
        raise UserError(f"{option} {address}: no Ray cluster answers there ({reason})", START_RAY) from None


def equal_priority_ray_workers() -> None:
    """Ray workers of the instances and nodes this process starts run at its own priority, as the local pool's
    workers do: at Ray's default (nice 15), any busy process on the machine starves them and a render run on
    Ray is many times slower than on the pool. A niceness the user set in the environment is kept."""
    os.environ.setdefault(RAY_WORKER_NICENESS, "0")


def connect_ray(address: str) -> bool:
    """Connect this process to Ray: ``auto`` joins the cluster named by ``RAY_ADDRESS`` or the one
    ``ray start`` runs on this machine, else starts a local instance; HOST:PORT joins that cluster's
    head. Returns whether this call connected (and so must ``ray.shutdown()``); a process already
    connected (a notebook, a test) keeps its connection. Errors name :data:`RAY_OPTION`."""
    option = RAY_OPTION
    if address != "auto" and _host_port(address) is None:
        raise UserError(
            f"{option} {address!r} is neither 'auto' nor HOST:PORT",
            f"give {option} auto, or the address `ray start --head` printed",
        )
    try:
        import ray
    except ImportError:
        raise UserError(f"{option} needs Ray, which is not installed", INSTALL_RAY) from None
    if ray.is_initialized():
        return False
    if address != "auto":
        _check_reachable(address, option)
    elif _host_port(os.environ.get("RAY_ADDRESS", "")) is not None:
        _check_reachable(os.environ["RAY_ADDRESS"], "RAY_ADDRESS")
    equal_priority_ray_workers()
    try:
        ray.init(
            address=None if address == "auto" else address,
            include_dashboard=False,
            log_to_driver=False,
            logging_level=logging.ERROR,
        )
    except ConnectionError as exc:
        raise UserError(f"{option} {address}: {' '.join(str(exc).split())}", START_RAY) from None
    return True


@contextmanager
def local_ray(num_cpus: int) -> Iterator[str]:
    """A new Ray instance of ``num_cpus`` CPUs on this machine, this process its driver and its workers at this
    process's priority; yields the head's address (for other drivers to join); shut down at the end."""
    import ray

    equal_priority_ray_workers()
    ray.init(
        address="local", num_cpus=num_cpus, include_dashboard=False, log_to_driver=False, logging_level=logging.ERROR
    )
    try:
        yield ray.get_runtime_context().gcs_address
    finally:
        ray.shutdown()


@contextmanager
def simulated_ray_cluster(nodes: int) -> Iterator[str]:
    """``nodes`` Ray nodes of 1 CPU each simulated on this machine (Ray's ``cluster_utils``), this process their
    driver; yields the head's address; every node stopped at the end."""
    import ray
    from ray.cluster_utils import Cluster

    equal_priority_ray_workers()
    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1, "include_dashboard": False})
    try:
        for _ in range(nodes - 1):
            cluster.add_node(num_cpus=1)
        cluster.wait_for_nodes()
        ray.init(address=cluster.address, log_to_driver=False, logging_level=logging.ERROR)
        yield cluster.address
    finally:
        ray.shutdown()
        cluster.shutdown()


@contextmanager
def open_executor(workers: int | None = None, ray: str | None = None) -> Iterator[Executor]:
    """The executor a command line asks for. Without ``ray``: ``workers`` local processes (None or 1:
    this process). With ``ray`` (``auto`` or HOST:PORT, given by :data:`RAY_OPTION`): Ray tasks, at most
    ``workers`` at once (None: as many as the cluster's CPUs). Ray is disconnected (a local instance
    stopped) at the end."""
    if ray is None:
        if (workers or 1) == 1:
            yield InProcess()
            return
        with LocalPool(workers) as pool:
            yield pool
        return
    connected = connect_ray(ray)
    watchdog = _start_ray_watchdog() if connected else None
    try:
        yield RayExecutor(workers)
    finally:
        if connected:
            import ray as ray_module

            ray_module.shutdown()
        if watchdog is not None:  # nothing left to watch
            watchdog.kill()
            watchdog.wait()


def _start_time(pid: int) -> str | None:
    """When process ``pid`` started (clock ticks since boot: tells it from a later process of the same id)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[19]
    except (OSError, IndexError):
        return None


def _processes_below(root: int) -> dict[int, str]:
    """Every process below ``root`` (children, theirs, ...) with its start time, from /proc."""
    children: dict[int, list[int]] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            ppid = int(stat.read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, IndexError, ValueError):  # ended while we looked
            continue
        children.setdefault(ppid, []).append(int(stat.parent.name))
    below: dict[int, str] = {}
    todo = [root]
    while todo:
        for pid in children.get(todo.pop(), []):
            start = _start_time(pid)
            if start is not None:
                below[pid] = start
                todo.append(pid)
    return below


def watch_ray_instance(driver: int, known: dict[int, str]) -> None:
    """The watchdog of a Ray instance that ``driver`` (this process's parent) started: while the driver
    lives, remember every process below it (from the start: ``known``, pid -> start time, listed by the
    driver, so that a driver killed before this process looked is covered too); once it is gone (it was
    killed: a driver that ends normally stops its watchdog first), SIGKILL those still running. Ray ends the
    GCS, raylet and workers with their parent, but Ray 2.60 leaves ``ray::DashboardAgent`` and
    ``ray::RuntimeEnvAgent`` running, deaf to SIGTERM."""
    me = os.getpid()
    seen = dict(known)
    while os.getppid() == driver:
        seen |= {pid: start for pid, start in _processes_below(driver).items() if pid != me}
        time.sleep(RAY_WATCH_S)
    for pid, start in seen.items():
        if _start_time(pid) == start:  # the same process, not a new one that reuses its id
            with suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)


def _start_ray_watchdog() -> subprocess.Popen | None:
    """A :func:`watch_ray_instance` process for the Ray instance this process just started, if it started one
    (Linux: it reads /proc); None otherwise."""
    import ray

    started_here = getattr(getattr(ray._private.worker, "_global_node", None), "head", False)
    if not (started_here and sys.platform.startswith("linux")):
        return None
    known = _processes_below(os.getpid())
    code = f"from gicore.executor import watch_ray_instance; watch_ray_instance({os.getpid()}, {known!r})"
    return subprocess.Popen(
        [sys.executable, "-c", code],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,  # a Ctrl-C at the terminal is the driver's to handle, not the watchdog's
    )


@dataclass(frozen=True)
class ExecutorOptions:
    """Where a command's renders run: the command-line form of :func:`open_executor` (its options are
    derived from these fields by :mod:`gicore.options`)."""

    #: Where the renders run: 'local' (this process, or --workers spawned processes) or 'ray' (Ray tasks).
    executor: Literal["local", "ray"] = "local"
    #: With --executor ray, the cluster: 'auto' (the one in RAY_ADDRESS or one `ray start` runs here, else a
    #: new local one, stopped at the end) or HOST:PORT of a head (default: auto).
    ray_address: str | None = field(default=None, metadata={"metavar": "auto|HOST:PORT"})
    #: Local rendering processes (default 1); with --executor ray, tasks at once (default: as many as the cluster
    #: has CPUs).
    workers: int | None = field(default=None, metadata=THREADS)

    def check(self) -> None:
        if self.executor == "local" and self.ray_address is not None:
            raise UserError("--ray-address needs --executor ray", "add --executor ray, or leave out --ray-address")
        if self.executor == "ray":
            try:
                import ray  # noqa: F401
            except ImportError:
                raise UserError("--executor ray needs Ray, which is not installed", INSTALL_RAY) from None

    def open(self) -> AbstractContextManager[Executor]:
        """The executor these options ask for (a context manager: Ray disconnected, pools ended at its exit)."""
        ray = (self.ray_address or "auto") if self.executor == "ray" else None
        return open_executor(self.workers, ray)

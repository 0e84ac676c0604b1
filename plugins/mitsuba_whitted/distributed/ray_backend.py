"""Tasks on Ray: a local Ray started for the job, or an existing cluster.

Each task asks Ray for one CPU and its worker renders with one Dr.Jit
thread, so a node runs as many tasks at once as it has CPUs. At most two
tasks per worker are in flight; the others wait here, so Ctrl-C has only
those few to cancel. Ray runs a task again when its worker process or node
dies (up to :data:`MAX_RETRIES` times); a task whose Python code fails is
not retried, since it would fail the same way.

Every worker process registers this package's plugins and sets the job's
variant before it loads a scene, and checks that its Mitsuba is the job's.
Scenes travel as :class:`.scene.SceneBundle` objects with their files'
contents, put in Ray's object store once per job, so nodes need no shared
file system; they do need this package installed, at the same version.

The command that connects must run on a node of the cluster (started with
``ray start --address=HEAD:PORT`` there), as Ray drivers do. Ray's own
servers listen on every interface of a node and are reached at the node's
address: use token authentication (``RAY_AUTH_MODE=token``) on a network
that others share.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import secrets
import signal
import socket
import sys
import threading
from collections import deque

import ray
import ray.exceptions

from ..errors import ClusterError
from ..interrupt import STOPPING, stderr_kept_back
from .scene import load_bundle
from .task import Environment, make_integrator, prepare_process, render_task

#: Times Ray starts a task again after its worker process or node died.
MAX_RETRIES = 3
#: Seconds to wait for a cluster's address to accept a connection.
CONNECT_SECONDS = 5.0
#: Attempts Ray makes to reach the cluster's control store when joining
#: (about 35 s each when something else answers at the address).
JOIN_ATTEMPTS = 2
#: Seconds between looks at the tasks in flight (Ctrl-C is seen between them).
POLL_SECONDS = 0.5
#: Seconds to fetch the image of a task that has finished.
FETCH_SECONDS = 60.0
#: Ray's log on the driver: its warnings, not its workers' output.
QUIET = {"log_to_driver": False, "logging_level": logging.WARNING}
#: Tasks in flight per worker: one running and one waiting on the worker,
#: so that it never waits for this process between two tasks.
IN_FLIGHT_PER_WORKER = 2


@ray.remote(num_cpus=1, max_retries=MAX_RETRIES)
def render_remote(task, environment, bundle, *contents):
    prepare_process(environment, threads=1)
    scene, integrator = _scene_and_integrator(task, bundle, contents)
    return render_task(scene, integrator, task)


#: This worker process's last scene and integrator, which a job's next
#: tasks usually share; one at a time, like the in-process backend.
_last: dict = {}


def _scene_and_integrator(task, bundle, contents):
    key = (task.scene, task.integrator_key)
    if key not in _last:
        _last.clear()
        _last[key] = (load_bundle(bundle, dict(zip(bundle.hashes, contents))),
                      make_integrator(task))
    return _last[key]


def host_and_port(address: str) -> tuple[str, int]:
    host, sep, port = address.split("://")[-1].rpartition(":")
    if not sep or not host or not port.isdigit():
        raise ClusterError(f"a cluster address is HOST:PORT (got '{address}').")
    return host.strip("[]"), int(port)


def check_reachable(address: str) -> None:
    """One sentence naming the address unless it accepts a connection
    within :data:`CONNECT_SECONDS`."""
    try:
        with socket.create_connection(host_and_port(address), timeout=CONNECT_SECONDS):
            pass
    except OSError as error:
        reason = error.strerror or type(error).__name__
        raise ClusterError(f"no Ray cluster answers at {address} "
                           f"({reason.lower()}).") from None


@contextlib.contextmanager
def _environment(values: dict, restored=()):
    """The environment variables ``values`` for the block; these and the
    variables ``restored`` are as they were before it afterwards."""
    before = {name: os.environ.get(name) for name in (*values, *restored)}
    os.environ.update(values)
    try:
        yield
    finally:
        for name, value in before.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


def _init(workers: int | None, address: str | None) -> None:
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    if address is None:
        _start_local(workers)
    else:
        _join(address)
    _stopping_signals_back_to_python()


#: The token of the local Rays this process starts. Ray would write a new
#: one to ~/.ray/auth_token, where the user's own ``ray start --head``
#: later finds it and turns token authentication on for a cluster whose
#: other nodes know no token. Given in the environment instead, it goes to
#: the Ray's processes, which take their environment from this one, and
#: ends with them. One for the life of this process: Ray's token loader
#: keeps the first token it reads.
_LOCAL_TOKEN = secrets.token_hex(32)


def _start_local(workers: int | None) -> None:
    # Ray says at every start that it protects a local Ray with a token.
    logging.getLogger("ray._private.authentication.authentication_token_setup").setLevel(
        logging.ERROR)
    # Ray sets RAY_AUTH_MODE for its processes when it finds the token.
    with _environment({"RAY_AUTH_TOKEN": _LOCAL_TOKEN}, restored=["RAY_AUTH_MODE"]):
        ray.init(address="local", num_cpus=workers, include_dashboard=False, **QUIET)


def _join(address: str) -> None:
    """Join the cluster at ``address``, or one sentence naming it. Ray's
    C++ core logs each failed attempt on stderr: those lines are kept from
    the terminal, and the last one gives the sentence its reason (a join
    that succeeds shows what Ray wrote)."""
    check_reachable(address)
    failure = None
    with stderr_kept_back() as ray_log, _environment(
            {"RAY_gcs_server_port_wait_time_s": str(JOIN_ATTEMPTS)}):
        try:
            ray.init(address=address, **QUIET)
        except (ConnectionError, ImportError, RuntimeError, ValueError,
                ray.exceptions.RayError) as error:
            failure = error
    if failure is not None:
        raise ClusterError(f"could not join the Ray cluster at {address}: "
                           f"{_join_failure(failure, ray_log.getvalue())}") from None
    sys.stderr.write(ray_log.getvalue())


#: A warning or error of Ray's C++ logging, its message in the group:
#: "[2026-01-01 10:00:00,123 W 2177 2177] gcs_client.cc:210: Failed to ...".
_RAY_LOG_LINE = re.compile(r"^\[[^\]]* [WEF] \d+ \d+\] [\w.]+:\d+: (.+)$", re.MULTILINE)


def _join_failure(error: BaseException, ray_log: str) -> str:
    """Why a join failed: the last message of Ray's log, which says more
    than the exception ("Failed to connect to Ray cluster at ..."), else
    the exception's message (without the help that Ray's authentication
    errors append), else its first line."""
    messages = _RAY_LOG_LINE.findall(ray_log)
    if messages:
        reason = messages[-1]
    else:
        lines = str(error).strip().splitlines()
        reason = getattr(error, "message", None) or (lines[0] if lines else type(error).__name__)
    reason = reason.strip().rstrip(".")
    if "authentication token" in reason.lower():
        reason += "; set RAY_AUTH_MODE=token and the cluster's RAY_AUTH_TOKEN"
    return reason + "."


def _stopping_signals_back_to_python() -> None:
    """Ray's C++ core, once this process has joined, handles SIGTERM itself:
    it prints a stack dump, then passes the signal on. The command says in
    one line that it stopped (see :mod:`..interrupt`), so the stopping
    signals go back to the handlers Python had."""
    if threading.current_thread() is not threading.main_thread():
        return  # Python sets handlers in its main thread only
    for signum in STOPPING:
        handler = signal.getsignal(signum)
        if handler is not None:
            signal.signal(signum, handler)


class RayBackend:
    """Runs a job's tasks on the Ray this process has joined, at most
    :data:`IN_FLIGHT_PER_WORKER` per worker at a time."""

    def __init__(self, workers: int, address: str | None):
        self.workers = workers
        self.description = (f"{workers} workers on the Ray cluster at {address}" if address
                            else f"{workers} workers on a local Ray")
        self.tasks_run = 0
        #: Tasks cancelled when the last job stopped early.
        self.cancelled: list = []

    @classmethod
    @contextlib.contextmanager
    def start(cls, workers: int | None, address: str | None):
        """Start a local Ray (``address`` None) with ``workers`` CPUs, or
        join a cluster and use ``workers`` of its CPUs (default: all);
        stop or leave it when the block ends."""
        _init(workers, address)
        try:
            yield cls(workers or max(1, int(ray.cluster_resources().get("CPU", 1))), address)
        finally:
            ray.shutdown()

    def run(self, tasks, scenes, on_result) -> None:
        environment = Environment.here()
        shipped = self._ship({task.scene for task in tasks}, scenes)
        pending, in_flight = deque(enumerate(tasks)), {}
        self.cancelled = []
        try:
            while pending or in_flight:
                while pending and len(in_flight) < IN_FLIGHT_PER_WORKER * self.workers:
                    index, task = pending.popleft()
                    bundle, contents = shipped[task.scene]
                    in_flight[render_remote.remote(task, environment, bundle, *contents)] = index
                done, _ = ray.wait(list(in_flight), num_returns=1, timeout=POLL_SECONDS)
                for ref in done:
                    index = in_flight.pop(ref)
                    image = self._fetch(ref, tasks[index], scenes[tasks[index].scene])
                    self.tasks_run += 1
                    on_result(index, image)
        finally:
            for ref in in_flight:
                ray.cancel(ref, force=True)
            self.cancelled = list(in_flight)

    @staticmethod
    def _ship(digests, scenes) -> dict:
        """Each scene's bundle and its files' contents in the object store,
        a content shared by several scenes once."""
        stored, shipped = {}, {}
        for digest in sorted(digests):
            bundle, contents = scenes[digest].bundle()
            for key in bundle.hashes:
                if key not in stored:
                    stored[key] = ray.put(contents[key])
            shipped[digest] = (ray.put(bundle), [stored[key] for key in bundle.hashes])
        return shipped

    @staticmethod
    def _fetch(ref, task, source):
        try:
            return ray.get(ref, timeout=FETCH_SECONDS)
        except ray.exceptions.RayTaskError as error:
            cause = error.cause
            if isinstance(cause, (RuntimeError, ValueError, OSError)):
                raise cause from None
            raise ClusterError(f"a task of {source.label} (seed {task.seed}) "
                               f"failed: {type(cause).__name__}: {cause}") from None
        except ray.exceptions.RayError as error:
            raise ClusterError(
                f"a task of {source.label} (seed {task.seed}) was lost on each "
                f"of its {MAX_RETRIES + 1} attempts ({type(error).__name__}).") from None

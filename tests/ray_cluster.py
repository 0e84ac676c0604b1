"""A real Ray cluster on this machine for the tests: a head node and a
second worker node, each its own ``ray start`` process, reached through
127.0.0.1 and protected by a token of its own unless a test asks for
other settings."""

from __future__ import annotations

import contextlib
import os
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

#: Seconds a node may take to start, and to stop.
START_SECONDS, STOP_SECONDS = 120, 30
#: Seconds the processes of a node started by ``ray start`` (without
#: ``--block``) have to end after SIGTERM: the head's GCS server and its
#: Python companion outlive it for tens of seconds, and nothing of the
#: test's cluster needs to end gracefully.
GROUP_STOP_SECONDS = 3
#: Each node's object store: the tests' images are a few kilobytes.
OBJECT_STORE_BYTES = 256 * 2**20


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


@dataclass
class Cluster:
    address: str
    env: dict


def _ray_start(arguments: list[str], env: dict) -> subprocess.Popen:
    ray = Path(sys.executable).with_name("ray")
    # Its own session, so that the node's processes can be stopped by group.
    return subprocess.Popen([str(ray), "start", "--block", "--disable-usage-stats",
                             "--num-cpus=1", f"--object-store-memory={OBJECT_STORE_BYTES}",
                             *arguments],
                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)


def _stop(process: subprocess.Popen) -> None:
    """SIGTERM makes ``ray start --block`` stop the node's processes (sent
    to them all at once instead, it can hang); whatever is left of its
    process group after that is killed."""
    process.terminate()
    try:
        process.wait(timeout=STOP_SECONDS)
    except subprocess.TimeoutExpired:
        pass
    with contextlib.suppress(ProcessLookupError):
        os.killpg(process.pid, signal.SIGKILL)
    process.wait(timeout=STOP_SECONDS)


#: Waits in a process of its own (the test process never joins Ray) until
#: the cluster has the given number of live nodes.
WAIT_FOR_NODES = """
import sys, time, ray
ray.init(address=sys.argv[1], log_to_driver=False, logging_level="WARNING")
deadline = time.monotonic() + float(sys.argv[3])
while sum(node["Alive"] for node in ray.nodes()) < int(sys.argv[2]):
    if time.monotonic() > deadline:
        sys.exit(f"the test cluster at {sys.argv[1]} did not reach {sys.argv[2]} nodes")
    time.sleep(0.5)
"""


def _wait_for_nodes(address: str, count: int, env: dict) -> None:
    subprocess.run([sys.executable, "-c", WAIT_FOR_NODES, address, str(count), str(START_SECONDS)],
                   env=env, check=True, timeout=START_SECONDS + 60, capture_output=True)


def _wait_for_port(port: int, head: subprocess.Popen) -> None:
    deadline = time.monotonic() + START_SECONDS
    while True:
        with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", port), 1):
            return
        if time.monotonic() > deadline or head.poll() is not None:
            raise TimeoutError(f"the test cluster's head did not start on port {port}")
        time.sleep(0.5)


@contextlib.contextmanager
def two_node_cluster(env: dict | None = None):
    """The cluster's address and the environment that reaches it: ``env``,
    by default this process's with a token of the cluster's own. Both nodes
    are stopped on exit, whatever happens inside."""
    # Short: Ray's socket paths under it must stay within 107 characters.
    temp = tempfile.mkdtemp(prefix="mwray")
    port = free_port()
    address = f"127.0.0.1:{port}"
    if env is None:
        env = dict(os.environ, RAY_AUTH_MODE="token", RAY_AUTH_TOKEN=secrets.token_hex(16))
    env = dict(env, RAY_USAGE_STATS_ENABLED="0")
    env.pop("RAY_ADDRESS", None)
    processes = []
    try:
        processes.append(_ray_start(["--head", f"--port={port}", "--node-ip-address=127.0.0.1",
                                     "--include-dashboard=false", f"--temp-dir={temp}"], env))
        _wait_for_port(port, processes[0])
        processes.append(_ray_start([f"--address={address}", "--node-ip-address=127.0.0.1",
                                     f"--dashboard-agent-listen-port={free_port()}"], env))
        _wait_for_nodes(address, 2, env)
        yield Cluster(address, env)
    finally:
        for process in reversed(processes):
            _stop(process)
        shutil.rmtree(temp, ignore_errors=True)


@contextlib.contextmanager
def cluster_of_commands(commands: list[str], address: str, env: dict):
    """The cluster at ``address`` that the shell ``commands`` start (``ray
    start`` lines, as a user types them), in ``env`` with Ray's programs on
    its ``PATH``. Each runs in a session of its own, whose process group
    Ray's processes stay in: they are stopped with it on exit."""
    env = dict(env, PATH=f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}")
    groups = []
    try:
        for command in commands:
            start = subprocess.Popen(["bash", "-c", command], env=env, start_new_session=True,
                                     stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
            groups.append(start.pid)
            output = start.communicate(timeout=START_SECONDS)[0]
            assert start.returncode == 0, f"{command}:\n{output}"
        _wait_for_nodes(address, len(commands), env)
        yield Cluster(address, env)
    finally:
        for group in reversed(groups):
            _stop_group(group)


def _stop_group(group: int) -> None:
    """SIGTERM to the process group, and SIGKILL to what is left of it after
    :data:`GROUP_STOP_SECONDS`."""
    deadline = time.monotonic() + GROUP_STOP_SECONDS
    with contextlib.suppress(ProcessLookupError):
        os.killpg(group, signal.SIGTERM)
        while time.monotonic() < deadline:
            os.killpg(group, 0)
            time.sleep(0.5)
        os.killpg(group, signal.SIGKILL)

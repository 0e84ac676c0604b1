"""References and batch renders on a real Ray cluster: identical bit for bit
to the in-process ones, also after a worker dies mid-job; Ctrl-C; the cache;
an unreachable address.

The cluster (a head node and a second worker node, each its own
``ray start``) is shared by the module and always stopped at its end. The
test process itself never joins Ray: each job runs in a process of its
own, as a user's command would.
"""

import importlib.util
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

from conftest import cli, one_line, read_only
from mitsuba_whitted.compare import render_reference
from mitsuba_whitted.distributed import SceneSource
from mitsuba_whitted.imageio import read_image

if importlib.util.find_spec("ray") is None:
    pytest.skip("Ray is not installed (pip install 'mitsuba-whitted[cluster]')",
                allow_module_level=True)

from ray_cluster import cluster_of_commands, free_port, two_node_cluster  # noqa: E402
from validation.scenes import REPORT_SCENE, ROOT  # noqa: E402

#: Every scene the project ships.
SCENES = [REPORT_SCENE, *sorted((ROOT / "scenes" / "cases").glob("*.xml"))]
GLASS = ROOT / "scenes" / "cases" / "glass_spheres.xml"
JOB = Path(__file__).parent / "tools" / "cluster_job.py"
README = ROOT / "README.md"
#: Seconds any command of these tests may take.
COMMAND_SECONDS = 300
#: The image size of the render-many tests, alone and in a batch.
RENDER_SIZE = "res=24"


@pytest.fixture(scope="module")
def cluster():
    with two_node_cluster() as running:
        yield running


def in_process_reference(scene, res, spp):
    return render_reference(SceneSource(scene, {"res": str(res)}), spp)


def _running_tasks():
    """Worker processes executing a render task now (Ray titles a worker's
    process with the function it runs)."""
    import psutil

    found = []
    for process in psutil.process_iter(["pid", "cmdline"]):
        command = " ".join(process.info["cmdline"] or [])
        if command.startswith("ray::render_remote"):
            found.append(process.info["pid"])
    return found


def _is_reference(entry) -> bool:
    """Whether a cache entry is a path reference (the cache holds Whitted's
    converged renders and a reference's photon part too): only a path
    reference has a variance and no gather radius."""
    with np.load(entry) as arrays:
        return "variance" in arrays.files and "radius_first" not in arrays.files


def test_reference_through_cluster_is_bit_identical_after_a_worker_is_killed(cluster, tmp_path):
    """``compare --cluster`` renders its reference on both nodes while a
    worker process running one of its tasks is killed; Ray runs that task
    again and the reference equals the in-process one bit for bit."""
    res, spp = 16, 16384
    command = [sys.executable, "-m", "mitsuba_whitted.cli", "compare", str(GLASS), "--quick",
               "-D", f"res={res}", "--reference-spp", str(spp), "--out", str(tmp_path),
               "--cluster", cluster.address]
    job = subprocess.Popen(command, cwd=ROOT, env=cluster.env, stdout=subprocess.PIPE,
                           stderr=subprocess.PIPE, text=True)
    killed = None
    deadline = time.monotonic() + COMMAND_SECONDS
    while killed is None and job.poll() is None and time.monotonic() < deadline:
        for pid in _running_tasks():
            os.kill(pid, signal.SIGKILL)
            killed = pid
            break
        time.sleep(0.02)
    out, err = job.communicate(timeout=COMMAND_SECONDS)
    assert killed is not None, "no task was seen running"
    assert job.returncode == 0, err
    (entry,) = [path for path in (tmp_path / "cache").glob("*.npz") if _is_reference(path)]
    with np.load(entry) as cached:
        reference = in_process_reference(GLASS, res, spp)
        np.testing.assert_array_equal(cached["image"], reference.image)
        np.testing.assert_array_equal(cached["variance"], reference.variance)
        assert int(cached["spp"]) == spp


def test_any_number_of_workers_gives_the_same_bits(cluster, tmp_path):
    out = tmp_path / "references.npz"
    res, spp = 16, 256
    subprocess.run([sys.executable, str(JOB), cluster.address, "workers", str(GLASS), str(res),
                    str(spp), str(out)], env=cluster.env, check=True, timeout=COMMAND_SECONDS)
    expected = in_process_reference(GLASS, res, spp)
    with np.load(out) as made:
        for workers in (1, 2, 16):
            np.testing.assert_array_equal(made[f"image_{workers}"], expected.image)
            np.testing.assert_array_equal(made[f"variance_{workers}"], expected.variance)


def test_ctrl_c_cancels_the_tasks_and_the_cache_stays_consistent(cluster, tmp_path):
    """Ctrl-C after the first of 16 tasks in flight: Ray cancels the others
    (those already running may just have finished), the cache holds no
    entry, not even a partial one; the next run renders all 16 tasks and
    stores the entry, and the run after it renders none."""
    result = subprocess.run([sys.executable, str(JOB), cluster.address, "interrupt",
                             str(GLASS), "16", "4096", str(tmp_path)], env=cluster.env,
                            check=True, timeout=COMMAND_SECONDS, capture_output=True, text=True)
    report = json.loads(result.stdout.strip().splitlines()[-1])
    assert report["interrupted"]
    assert len(report["cancelled"]) == 15
    assert set(report["cancelled"]) <= {"cancelled", "finished"}
    assert report["cancelled"].count("cancelled") >= 15 - 2
    assert report["entries_after_interrupt"] == []
    assert report["tasks_of_second_run"] == 16
    assert report["tasks_of_third_run"] == 0 and report["third_cached"]
    assert report["entries"] == ["key.npz"]


@pytest.fixture(scope="module")
def rendered_alone(tmp_path_factory):
    """Each scene as ``render`` writes it, by name: what both render-many
    tests compare with, so each scene is rendered once for the module."""
    folder = tmp_path_factory.mktemp("alone")
    images = {}
    for scene in SCENES:
        single = folder / f"{scene.stem}.exr"
        assert cli("render", str(scene), "-o", str(single), "-D", RENDER_SIZE,
                   timeout=COMMAND_SECONDS).returncode == 0
        images[scene.stem] = read_only(read_image(single))
    return images


def _render_many_matches_render(tmp_path, rendered_alone, *options, env=None):
    out = tmp_path / "many"
    result = cli("render-many", *map(str, SCENES), "--out", str(out), "-D", RENDER_SIZE, *options,
                 env=env, timeout=COMMAND_SECONDS)
    assert result.returncode == 0, result.stderr
    for scene in SCENES:
        np.testing.assert_array_equal(read_image(out / f"{scene.stem}.exr"),
                                      rendered_alone[scene.stem])


def test_render_many_on_the_cluster_writes_what_render_writes(cluster, rendered_alone, tmp_path):
    """Each worker registers the package's plugins (the report's scene uses
    phong, tartan, sphere_map, capped_cylinder and whitted) and rebuilds the
    scene's textures from the bytes it was sent."""
    _render_many_matches_render(tmp_path, rendered_alone, "--cluster", cluster.address,
                                env=cluster.env)


def test_render_many_on_a_local_ray_writes_what_render_writes(rendered_alone, tmp_path):
    env = dict(os.environ)
    env.pop("RAY_ADDRESS", None)
    _render_many_matches_render(tmp_path, rendered_alone, "--workers", "2", env=env)


def test_unreachable_cluster_is_one_sentence_naming_the_address(tmp_path):
    address = f"127.0.0.1:{free_port()}"
    result = cli("render-many", str(GLASS), "--out", str(tmp_path), "--cluster", address,
                 timeout=COMMAND_SECONDS)
    assert result.returncode != 0
    line = one_line(result.stderr)
    assert address in line and "no Ray cluster answers" in line
    assert not any(tmp_path.iterdir())


def without_ray_auth(env) -> dict:
    """``env`` without Ray's token settings (a user's shell has none)."""
    return {name: value for name, value in env.items() if not name.startswith("RAY_AUTH")}


def test_a_refused_join_is_one_sentence_without_rays_log(cluster, tmp_path):
    """A cluster that asks for a token the command lacks: Ray's C++ core
    logs each refused attempt on stderr; the user reads one sentence that
    names the address and what is missing."""
    env = without_ray_auth(cluster.env)
    result = cli("render-many", str(GLASS), "--out", str(tmp_path), "--cluster", cluster.address,
                 env=env, timeout=COMMAND_SECONDS)
    assert result.returncode == 2
    line = one_line(result.stderr)
    assert line.startswith(f"mitsuba-whitted: could not join the Ray cluster at {cluster.address}")
    assert "InvalidAuthToken" in line and "RAY_AUTH_TOKEN" in line
    assert not any(tmp_path.iterdir())


def readmes_cluster_recipe(port: int) -> list[str]:
    """The README's commands that start a cluster (its block of ``ray
    start`` lines), for a head on this machine at ``port``."""
    blocks = re.findall(r"```sh\n(.*?)```", README.read_text(), re.S)
    recipe = next(block for block in blocks if "ray start --head" in block)
    commands = [line.partition("#")[0].strip() for line in recipe.splitlines()]
    return [command.replace("HEAD", "127.0.0.1").replace("6379", str(port))
            for command in commands if command]


def test_the_readmes_cluster_recipe_works_after_a_local_ray(tmp_path):
    """``--workers`` in a fresh home leaves nothing there but Dr.Jit's
    kernel cache (Ray would write a token to ~/.ray/auth_token, which turns
    token authentication on for the user's next ``ray start --head``); then
    the README's recipe, run as written (a head and a node that know no
    token), makes a cluster of two nodes, which a command joins."""
    home = tmp_path / "home"
    home.mkdir()
    # Ray's files in a folder of the test's (short: Ray's socket paths
    # under it must stay within 107 characters), not in the machine's /tmp/ray.
    ray_files = Path(tempfile.mkdtemp(prefix="mwray"))
    env = dict(without_ray_auth(os.environ), HOME=str(home), RAY_TMPDIR=str(ray_files),
               RAY_USAGE_STATS_ENABLED="0")
    env.pop("RAY_ADDRESS", None)
    result = cli("render-many", str(GLASS), "--out", str(tmp_path / "out"), "-D", "res=8",
                 "--workers", "2", env=env, timeout=COMMAND_SECONDS)
    assert result.returncode == 0, result.stderr
    assert [path.name for path in home.iterdir()] == [".drjit"]
    port = free_port()
    try:
        with cluster_of_commands(readmes_cluster_recipe(port), f"127.0.0.1:{port}", env) as recipe:
            result = cli("render-many", str(GLASS), "--out", str(tmp_path / "out"), "-D", "res=8",
                         "--cluster", recipe.address, env=recipe.env, timeout=COMMAND_SECONDS)
            assert result.returncode == 0, result.stderr
    finally:
        shutil.rmtree(ray_files, ignore_errors=True)

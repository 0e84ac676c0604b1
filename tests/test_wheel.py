"""``pip install`` gives a working package: the wheel, built from the
package's own files and installed with its dependencies into a fresh
virtual environment outside the checkout, renders the shipped scenes from
the command line and from Python, and runs ``bench`` and ``compare`` on
them, with nothing of the checkout in reach."""

import os
import shutil
import subprocess
import sys
import venv
import zipfile
from pathlib import Path

import pytest

from validation.scenes import ROOT

#: What a build reads; copied out, so that no build folder of the checkout
#: (setuptools keeps files there that the tree no longer has) gets in.
SOURCES = ["pyproject.toml", "README.md", "LICENSE", "plugins"]

DATA = {"mitsuba_whitted/data/scenes/cosc363.xml",
        "mitsuba_whitted/data/scenes/cases/glass_spheres.xml",
        "mitsuba_whitted/data/textures/lemons.png",
        "mitsuba_whitted/data/textures/pink_elephant.png"}

#: A Python render through the shipped scene, and where its files come from.
PYTHON_RENDER = """
import numpy as np, mitsuba as mi, mitsuba_whitted
mitsuba_whitted.set_variant()
scene = mitsuba_whitted.scenes.load("cosc363", res=24, aa="none")
image = np.asarray(mi.render(scene))
assert image.shape == (24, 24, 3) and np.isfinite(image).all() and image.max() > 0.1
from importlib.metadata import entry_points
assert [ep.load() for ep in entry_points(group="mitsuba")] == [mitsuba_whitted]
print(mitsuba_whitted.__file__)
print(mitsuba_whitted.scenes.path("cosc363"))
"""


def run(args, cwd, timeout=600):
    """``args`` with no path of the checkout in the environment."""
    env = {key: value for key, value in os.environ.items()
           if key not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV")}
    result = subprocess.run([str(a) for a in args], cwd=cwd, env=env, capture_output=True,
                            text=True, timeout=timeout)
    assert result.returncode == 0, f"{args}: {result.stdout[-2000:]}{result.stderr[-4000:]}"
    return result


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    source = tmp_path_factory.mktemp("source")
    for name in SOURCES:
        if (ROOT / name).is_dir():
            shutil.copytree(ROOT / name, source / name,
                            ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
        else:
            shutil.copy(ROOT / name, source / name)
    out = tmp_path_factory.mktemp("wheel")
    run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--quiet", "-w", out, source],
        cwd=out)
    return next(out.glob("mitsuba_whitted-*.whl"))


@pytest.fixture(scope="module")
def installed(wheel, tmp_path_factory) -> Path:
    """The ``bin`` folder of a fresh environment with the wheel installed,
    its dependencies at the versions ``make`` tests (constraints.txt)."""
    home = tmp_path_factory.mktemp("venv")
    venv.create(home, with_pip=True)
    run([home / "bin" / "python", "-m", "pip", "install", "--quiet",
         "-c", ROOT / "constraints.txt", wheel], cwd=home)
    return home / "bin"


@pytest.fixture
def workdir(tmp_path) -> Path:
    assert not tmp_path.resolve().is_relative_to(ROOT.resolve())
    return tmp_path


def test_the_wheel_holds_the_scenes_and_textures_as_files(wheel):
    with zipfile.ZipFile(wheel) as archive:
        names = set(archive.namelist())
        assert DATA <= names
        # Real files, not the checkout's links (a link's mode is 0o120000).
        modes = {archive.getinfo(name).external_attr >> 16 for name in DATA}
        assert all(mode & 0o170000 != 0o120000 for mode in modes)


def test_render_a_shipped_scene_by_name(installed, workdir):
    run([installed / "mitsuba-whitted", "render", "cosc363", "-o", "out.png", "-D", "res=32"],
        cwd=workdir)
    assert (workdir / "out.png").stat().st_size > 0


def test_bench_quick_defaults_to_the_shipped_scene(installed, workdir):
    result = run([installed / "mitsuba-whitted", "bench", "--quick"], cwd=workdir)
    assert f"scene {installed.parent}" in result.stdout
    assert "mitsuba_whitted/data/scenes/cosc363.xml at 96x96" in result.stdout


def test_compare_quick_of_a_shipped_scene(installed, workdir):
    run([installed / "mitsuba-whitted", "compare", "cosc363", "--quick", "-D", "res=32"],
        cwd=workdir)
    assert (workdir / "compare-cosc363" / "report.md").is_file()


def test_a_python_render_of_a_shipped_scene(installed, workdir):
    package, scene = run([installed / "python", "-c", PYTHON_RENDER],
                         cwd=workdir).stdout.splitlines()[-2:]
    environment = installed.parent.resolve()
    assert Path(package).resolve().is_relative_to(environment)
    assert Path(scene).resolve().is_relative_to(environment)

"""The README's Python examples run as printed: the first renders, writes
its image, and its bad parameter update is one sentence that changes
nothing; the report scene's example changes the scene through
``mi.traverse`` and takes a gradient with respect to a texture."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

# Run after the example, in its process: the refused update left the scene
# as it was, so reading the parameter back and rendering again agree with
# what came before it.
AFTERWARDS = """
import numpy as np
assert mi.traverse(scene)["ball.bsdf.exponent"] == 40
again = mi.render(scene)
assert np.array_equal(np.asarray(again), np.asarray(image))
assert np.isfinite(np.asarray(image)).all() and np.asarray(image).max() > 0
"""


def readme_python_example(heading: str = "## From Python") -> str:
    """The first Python block after ``heading``."""
    text = (ROOT / "README.md").read_text()
    section = text.index(heading)
    start = text.index("```python\n", section) + len("```python\n")
    return text[start:text.index("```", start)]


def test_the_readme_python_example_runs(tmp_path):
    result = subprocess.run([sys.executable, "-c", readme_python_example() + AFTERWARDS],
                            capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert result.stdout.splitlines()[-1] == (
        "phong: parameter 'exponent' must be a finite number >= 0 (got -1)")
    assert (tmp_path / "ball.exr").stat().st_size > 0


# Run after the report scene's example, in its process: both changes show
# in the image, and the gradient is finite, reaches the lemons' texels that
# rays see, and only those.
REPORT_SCENE_AFTERWARDS = """
import numpy as np
before = mi.render(mitsuba_whitted.scenes.load("cosc363", res=128, aa="none",
                                               texture_format="variant"))
changed = np.asarray(dr.detach(image)) != np.asarray(before)
assert changed.any(axis=2).mean() > 0.01
values = np.asarray(gradient)
assert values.shape == (512, 512, 3) and np.isfinite(values).all()
assert 0 < (values > 0).mean() < 0.5 and (values >= 0).all()
print(sorted(k for k in params.keys() if k.startswith(("tartan_ball.", "glass_ball."))))
"""


def test_the_readme_report_scene_example_runs(tmp_path):
    code = readme_python_example("### The report's scene from Python") + REPORT_SCENE_AFTERWARDS
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                            timeout=600, cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    keys = result.stdout.splitlines()[-1]
    assert "'glass_ball.bsdf.eta'" in keys
    assert "'tartan_ball.bsdf.diffuse_reflectance.color'" in keys
    assert (tmp_path / "cosc363.png").stat().st_size > 0

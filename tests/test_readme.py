"""The README's Python example runs as printed: it renders, writes its
image, and its bad parameter update is one sentence that changes nothing."""

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


def readme_python_example() -> str:
    text = (ROOT / "README.md").read_text()
    section = text.index("## From Python")
    start = text.index("```python\n", section) + len("```python\n")
    return text[start:text.index("```", start)]


def test_the_readme_python_example_runs(tmp_path):
    result = subprocess.run([sys.executable, "-c", readme_python_example() + AFTERWARDS],
                            capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert result.stdout.splitlines()[-1] == (
        "phong: parameter 'exponent' must be a finite number >= 0 (got -1)")
    assert (tmp_path / "ball.exr").stat().st_size > 0

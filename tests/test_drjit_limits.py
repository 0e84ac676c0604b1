"""The Dr.Jit 1.5 limits that the gradients' tree replay works around,
each reduced to a script in ``tools/drjit_limits``: each still fails as
its script says, and the way around it works. A Dr.Jit that lifts a limit
fails its test here, and the workaround can go (docs/design.md, Gradients).

The scripts run in child processes: two of the failures abort the
process."""

import os
import subprocess
import sys
from pathlib import Path

LIMITS = Path(__file__).resolve().parent / "tools" / "drjit_limits"


def run(script: str, *arguments: str) -> tuple:
    """Exit code and output (stdout and stderr) of a limit's script. The
    child loads the libLLVM this process's Dr.Jit uses (the package
    chooses it and sets ``DRJIT_LIBLLVM_PATH``)."""
    child = subprocess.run([sys.executable, str(LIMITS / script), *arguments],
                           capture_output=True, text=True, timeout=300, env=dict(os.environ))
    return child.returncode, child.stdout + child.stderr


def test_a_branch_whose_input_carries_a_derivative_aborts_a_differentiating_loop():
    for arguments in ((), ("freeze",)):
        code, output = run("if_in_loop.py", *arguments)
        assert code != 0 and "unknown variable" in output, output[-2000:]


def test_the_same_loop_with_a_select_gives_the_closed_form_gradient():
    """Lanes 0..4, even i below each: sum (2 i)^2 is 16 for lanes 3 and 4
    (i = 2), and its derivative in x = 2 is 2 x i^2 = 16 each."""
    for arguments in (("select",), ("select", "freeze")):
        code, output = run("if_in_loop.py", *arguments)
        assert code == 0, output[-2000:]
        assert "ok [0, 0, 0, 16, 16] [32]" in output


def test_a_product_loop_differentiated_by_its_trajectory_does_not_compile():
    code, output = run("product_loop.py")
    assert code != 0 and "parsing failed" in output, output[-2000:]


def test_a_sum_loop_reading_the_differentiated_variable_is_not_recorded():
    code, output = run("product_loop.py", "sums")
    assert code != 0 and "not permitted" in output, output[-2000:]

"""The programs that the package runs in child processes, one file each.

A child runs its program by path (``python FILE``), not with ``python -m``:
``-m`` would import the package first, and with it Dr.Jit, a libLLVM and
Mitsuba. The libLLVM probe must start without any libLLVM loaded, and the
FLIP worker needs none of them. The folder holds only these programs, so
that the child's first import path (the program's folder) hides no module
of the standard library or of Dr.Jit.
"""

from __future__ import annotations

import sys
from pathlib import Path


def command(program: str, *args: str) -> list[str]:
    """The command line that runs ``program`` (a file of this folder,
    without ``.py``) with ``args`` in this interpreter."""
    return [sys.executable, str(Path(__file__).with_name(f"{program}.py")), *args]

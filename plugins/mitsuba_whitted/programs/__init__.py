"""The programs that the package runs in child processes, one file each.

A child runs its program by path (``python FILE``), not with ``python -m``:
``-m`` would import the package first, and with it Dr.Jit, a libLLVM and
Mitsuba. The libLLVM probe must start without any libLLVM loaded, and the
FLIP worker needs none of them. The folder holds only these programs, so
that the child's first import path (the program's folder) hides no module
of the standard library or of Dr.Jit.

Nothing in the package imports them (:func:`mitsuba_whitted.system.program_command`
makes their command lines), so that they may import any part of it.
"""

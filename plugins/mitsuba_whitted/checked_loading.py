"""Mitsuba's scene loaders that raise what the user must read.

When a plugin of this package refuses a parameter while ``mi.load_dict``,
``mi.load_file`` or ``mi.load_string`` makes it, Mitsuba's loader raises a
``RuntimeError`` whose message holds the plugin's whole Python traceback
after its own heading: seven to nine lines, the sentence last. That is all
the loader passes on (it keeps no exception object, so nothing is in
``__cause__``). Importing the package puts :func:`checked_loader` around
the three loaders: the package's error is raised anew, its sentence in
``str(error)`` with where the loader says the plugin is ("..., at
dictionary node "integrator"", "..., at scene.xml (line 3, col 30)").
Errors of Mitsuba's own plugins pass through as Mitsuba raises them.
"""

from __future__ import annotations

import functools

from .errors import own_loading_error, raising_own

#: The loaders of ``mitsuba`` that make plugins from a description.
LOADERS = ("load_dict", "load_file", "load_string")


def checked_loader(mitsuba_load):
    """``mitsuba_load`` that raises this package's errors unwrapped."""
    @functools.wraps(mitsuba_load)
    def load(*args, **kwargs):
        with raising_own(own_loading_error):
            return mitsuba_load(*args, **kwargs)

    return load

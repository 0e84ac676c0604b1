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

A value of ``None`` anywhere in a dictionary ends the interpreter in
Mitsuba 3.9.1's ``load_dict`` (a segmentation fault, whatever the plugin):
``load_dict`` refuses it first, naming the plugin, the key and the node.
"""

from __future__ import annotations

import functools

from .errors import ParameterError, own_loading_error, raising_own

#: The loaders of ``mitsuba`` that make plugins from a description.
LOADERS = ("load_dict", "load_file", "load_string")


def checked_loader(mitsuba_load):
    """``mitsuba_load`` that raises this package's errors unwrapped."""
    @functools.wraps(mitsuba_load)
    def load(*args, **kwargs):
        if mitsuba_load.__name__ == "load_dict":
            refuse_none_values(args[0] if args else kwargs.get("dict"))
        with raising_own(own_loading_error):
            return mitsuba_load(*args, **kwargs)

    return load


def refuse_none_values(description: dict, node: str = "") -> None:
    """A :class:`ParameterError` for the first ``None`` in the scene
    dictionary ``description`` (nested dictionaries included), which
    Mitsuba's ``load_dict`` would crash on; anything but a dictionary is
    left to Mitsuba."""
    if not isinstance(description, dict):
        return
    for key, value in description.items():
        where = f"{node}.{key}" if node else str(key)
        if value is None:
            plugin = description.get("type", "load_dict")
            place = f', at dictionary node "{node}"' if node else ""
            raise ParameterError(str(plugin), str(key),
                                 f"is None: give it a value or leave it out{place}")
        refuse_none_values(value, where)

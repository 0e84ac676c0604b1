"""The scenes this package ships: the report's scene ``cosc363`` and the
example cases, by name, from any install.

They are package data (``data/scenes`` and the ``data/textures`` they
read), found with :mod:`importlib.resources`, so a wheel installed
anywhere renders them as a checkout does; the checkout's top-level
``scenes`` and ``textures`` are links to the same folders. A scene names
its textures relative to its own file (``../textures/lemons.png``), which
holds in every form since both folders always sit side by side.

    scene = mitsuba_whitted.scenes.load("cosc363", res=300)
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from .errors import UsageError
from .files import check_readable

#: The name of the report's scene.
REPORT = "cosc363"


def _folder() -> Path:
    # An installed package is a folder of files (pip unpacks wheels), so the
    # resource is a real path that Mitsuba can open, relative textures too.
    return Path(str(resources.files(__package__) / "data" / "scenes"))


def shipped() -> dict[str, Path]:
    """Every shipped scene's file by name (its file's stem), sorted by name."""
    return {path.stem: path for path in sorted(_folder().rglob("*.xml"), key=lambda p: p.stem)}


def path(name: str) -> Path:
    """The file of the shipped scene ``name``; a :class:`UsageError` that
    lists the shipped names if there is none."""
    return _named(name, f"there is no shipped scene '{name}'")


def resolve(argument: str | Path) -> Path:
    """The scene file a command line names: an existing file or folder
    (refused by :func:`.files.check_readable`) first, else a shipped scene of
    that name. A missing file with no folder and no suffix in its name is
    taken for a scene's name, so the error lists the shipped ones."""
    given = Path(argument)
    if given.exists() or given.suffix or len(given.parts) > 1:
        return check_readable(given)
    return _named(str(argument), f"'{argument}' is neither a scene file nor a shipped scene")


def _named(name: str, unknown: str) -> Path:
    files = shipped()
    if name not in files:
        raise UsageError(f"{unknown}; the shipped scenes are {', '.join(files)}.")
    return files[name]


def load(name: str, **defines):
    """The shipped scene ``name`` loaded by :func:`mitsuba_whitted.load_file`,
    with ``defines`` setting its ``<default>`` values as ``-D`` does
    (``res=300``); plugins are registered for the active variant."""
    from . import load_file

    return load_file(str(path(name)), **defines)

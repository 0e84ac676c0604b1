"""What a scene file reads, as Mitsuba's parser finds it with the defines:
the XML files (the scene and its includes), and each file that a property
named ``filename`` names (textures, meshes, environment maps, spectra).

The commands refuse to write over any of them (:func:`check_not_read`):
an image written over the texture or the include it was rendered from
would be a loss the user finds only later. And a film without pixels is
refused by its own name (:func:`check_films`) before Mitsuba's camera
divides by its size and blames its field of view, an image whose header
declares more pixels than memory holds (:func:`check_images`) before
Mitsuba allocates them, and a scene path that is not UTF-8
(:func:`check_utf8`) before Mitsuba's parser fails on it.
"""

from __future__ import annotations

import os
from pathlib import Path

import mitsuba as mi

from .errors import ParameterError, UsageError
from .files import ReadError, cannot_write, check_readable
from .imageio import image_refusal
from .system import shown


def parse(path: str | Path, defines: dict):
    """Mitsuba's parse of the scene file (no object is made yet)."""
    check_utf8(path, defines)
    config = mi.parser.ParserConfig(mi.variant())
    return mi.parser.parse_file(config, str(check_readable(path)), **defines)


def check_utf8(path: str | Path, defines: dict) -> None:
    """A :class:`~.files.ReadError` for a scene path or a define that is not
    UTF-8. Python hands such bytes (a file named ``$'sc\\xffene.xml'``) on
    as lone surrogates, and Mitsuba takes strings as UTF-8 only: its parser
    failed in nanobind's type error. Refused rather than worked around:
    Mitsuba finds the scene's includes and textures by the scene's own
    path, so no other path would read the same scene; a link to the file
    under a UTF-8 name, beside it, does."""
    if not _is_utf8(path):
        raise ReadError(f"scene file '{shown(str(path))}' has a path that "
                        "is not UTF-8, which Mitsuba cannot open; rename it, or link to it "
                        "under a UTF-8 name.")
    for name, value in defines.items():
        if not (_is_utf8(name) and _is_utf8(value)):
            raise ReadError(f"-D {shown(name)}={shown(str(value))} is not "
                            "UTF-8, which Mitsuba's parser cannot take.")


def _is_utf8(value) -> bool:
    """Whether ``value``'s text is UTF-8 (has no lone surrogate)."""
    text = str(value)
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


def files_read(path: str | Path, defines: dict) -> list[Path]:
    """The files the scene reads, as real paths (links followed). A
    relative name is looked up where Mitsuba looks: beside the scene file
    (an include's names too), then in the working folder; both are
    counted where both exist."""
    state = parse(path, defines)
    found = {Path(str(name)) for name in state.files}
    for _, candidates in nodes_naming_files(state, path):
        found.update(candidates)
    return sorted({Path(os.path.realpath(file)) for file in found})


def nodes_naming_files(state, path: str | Path):
    """Each node of a parsed scene that names a file (its ``filename``),
    with the existing files the name may refer to, in the order Mitsuba
    looks for them."""
    folders = [Path(path).parent, Path.cwd()]
    for node in state.nodes:
        name = node.props.get("filename")
        if isinstance(name, str):
            yield node, [folder / name for folder in folders if (folder / name).is_file()]


def first_sensor(scene: mi.Scene, path: str | Path) -> mi.Sensor:
    """The sensor a command renders the scene loaded from ``path`` from:
    its first; a :class:`UsageError` where it has none."""
    if not scene.sensors():
        raise UsageError(f"scene '{path}' has no sensor to render from; add a <sensor>.")
    return scene.sensors()[0]


def check_images(state, path: str | Path) -> None:
    """A :class:`~.errors.ParameterError` for an image the parsed scene
    reads (a ``bitmap``'s, an ``envmap``'s) whose header declares more
    pixels than the memory available holds, or than the file can hold
    (:func:`.imageio.image_refusal`), before Mitsuba allocates them."""
    for node, candidates in nodes_naming_files(state, path):
        refusal = image_refusal(candidates[0]) if candidates else None
        if refusal:
            raise ParameterError(node.props.plugin_name(), "filename",
                                 f"names '{candidates[0]}': {refusal}; at "
                                 f"{mi.parser.file_location(state, node)}")


def check_not_read(outputs, scene: str | Path, defines: dict) -> None:
    """A :class:`~.files.WriteError` if writing one of ``outputs`` (files,
    or folders that a command fills) would replace a file the scene reads."""
    read = files_read(scene, defines)
    for output in outputs:
        target = Path(os.path.realpath(output))
        clash = next((file for file in read if target == file or target in file.parents), None)
        if clash is not None:
            what = "it" if clash == target else f"'{clash}' in it"
            raise cannot_write(output, f"scene '{scene}' reads {what}; choose another output")


def check_films(state) -> None:
    """A :class:`~.errors.ParameterError` for a film of a parsed scene
    whose width or height is below 1."""
    for node in state.nodes:
        if node.type != mi.ObjectType.Film:
            continue
        for side in ("width", "height"):
            if side in node.props and node.props[side] < 1:
                raise ParameterError(
                    node.props.plugin_name(), side,
                    f"must be at least 1 (got {node.props[side]}), at "
                    f"{mi.parser.file_location(state, node)}")

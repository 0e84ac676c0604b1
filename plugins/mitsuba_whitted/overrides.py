"""A scene file loaded with other settings than its own: another resolution,
another integrator depth, whether or not the file declares them as
``$``-parameters.

``-D name=value`` reaches only what a scene declares with ``<default>``, and
Mitsuba refuses a value that nothing uses, so a sweep over the resolution
of an arbitrary scene cannot go through defines alone. Here a setting goes
through the scene's own parameter where the property refers to one (so
other uses of that parameter follow, as with ``-D``), and into the XML
where the property is a literal or absent.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from contextlib import contextmanager
from pathlib import Path

import mitsuba as mi

from . import load_file
from .errors import UsageError
from .scene_files import check_utf8

#: Mitsuba's film size when a scene gives none (``hdrfilm``'s defaults).
DEFAULT_FILM_SIZE = (768, 576)


def load_with(path: Path, defines: dict, settings: dict) -> mi.Scene:
    """The scene of ``path`` with ``defines`` (as ``-D``) and ``settings``:
    ``res`` is the film's width in pixels (its height keeps the film's
    aspect ratio), ``sampler`` the type of the sensor's sampler, any other
    name an integer property of the integrator (``max_depth``,
    ``aa_max_depth``, ...)."""
    path = Path(path)
    if not settings:
        return load_file(path, **defines)
    # Refused here too, though Python reads the XML: every command reads
    # such a scene the same way, and the processes it starts cannot.
    check_utf8(path, defines)
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as error:
        raise UsageError(f"scene '{path}' is not well-formed XML "
                           f"({error}).") from None
    defines = dict(defines)
    for name, value in settings.items():
        if name == "res":
            _set_resolution(root, path, defines, int(value))
        elif name == "sampler":
            _set_sampler(_element(root, "sensor", path), value)
        else:
            _set_property(_element(root, "integrator", path), "integer", name, int(value),
                          defines)
    with _relative_paths_from(path.parent):
        return mi.load_string(ET.tostring(root, encoding="unicode"), parallel=False,
                              optimize=False, **defines)


def _element(root: ET.Element, where: str, path: Path) -> ET.Element:
    element = root.find(where)
    if element is None:
        raise UsageError(f"scene '{path}' has no <{where.replace('/', '><')}> "
                           "whose settings could be changed.")
    return element


#: The crop window's offset and size along each side of the film.
CROP = {"width": ("crop_offset_x", "crop_width"), "height": ("crop_offset_y", "crop_height")}


def _set_resolution(root: ET.Element, path: Path, defines: dict, width: int) -> None:
    """The film ``width`` pixels wide; its aspect kept, and its crop window
    where it was on the film, in proportion."""
    film = _element(root, "sensor/film", path)
    old = {axis: _resolved(root, film, axis, default, defines)
           for axis, default in zip(CROP, DEFAULT_FILM_SIZE)}
    crop = {name: _resolved(root, film, name, None, defines)
            for names in CROP.values() for name in names}
    new = {"width": width, "height": max(1, round(width * old["height"] / old["width"]))}
    for axis, (offset_name, size_name) in CROP.items():
        _set_property(film, "integer", axis, new[axis], defines)
        offset, size = crop[offset_name], crop[size_name]
        if offset is None and size is None:
            continue
        scale = new[axis] / old[axis]
        start = min(round((offset or 0) * scale), new[axis] - 1)
        extent = round((old[axis] if size is None else size) * scale)
        _set_property(film, "integer", offset_name, start, defines)
        _set_property(film, "integer", size_name, max(1, min(extent, new[axis] - start)),
                      defines)


def _set_sampler(sensor: ET.Element, kind: str) -> None:
    """The sensor's sampler replaced by one of type ``kind`` that keeps only
    its sample count (a parameter the scene passes there stays in use; the
    other properties may be foreign to ``kind``)."""
    new = ET.SubElement(sensor, "sampler", type=kind)
    old = sensor.find("sampler")
    if old is not new:
        new.extend(old.findall("integer[@name='sample_count']"))
        sensor.remove(old)


def _resolved(root: ET.Element, parent: ET.Element, name: str, default, defines: dict):
    """The value of ``parent``'s integer property ``name``, its parameter
    resolved through ``defines`` or the scene's ``<default>``."""
    element = parent.find(f"integer[@name='{name}']")
    if element is None:
        return default
    value = element.get("value", "")
    if value.startswith("$"):
        parameter = value[1:]
        declared = root.find(f"default[@name='{parameter}']")
        if parameter not in defines and declared is None:
            raise UsageError(f"the film's {name} refers to ${parameter}, "
                               "which has no value: declare a <default> or pass -D.")
        value = defines.get(parameter) or declared.get("value")
    return int(value)


def _set_property(parent: ET.Element, tag: str, name: str, value: int, defines: dict) -> None:
    """Give ``parent``'s property ``name`` the value ``value``: through the
    parameter it refers to, if any, else in the XML."""
    element = parent.find(f"{tag}[@name='{name}']")
    if element is None:
        element = ET.SubElement(parent, tag, name=name)
    current = element.get("value", "")
    if current.startswith("$"):
        defines[current[1:]] = str(value)
    else:
        element.set("value", str(value))


@contextmanager
def _relative_paths_from(directory: Path):
    """Resolve the scene's relative file names (textures, meshes, includes)
    from its own directory, as ``mi.load_file`` does."""
    resolver = mi.file_resolver()
    saved = [resolver[index] for index in range(len(resolver))]
    resolver.prepend(str(directory.resolve()))
    try:
        yield
    finally:
        resolver.clear()
        for entry in saved:
            resolver.append(entry)

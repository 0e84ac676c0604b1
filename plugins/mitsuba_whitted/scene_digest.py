"""What identifies a scene file: the files it names, and content hashes of
it that both the reference cache and the distributed jobs use.

:func:`scene_digest` hashes the file as written: its bytes, the bytes of
every file it names (textures, meshes, includes) and its ``-D`` defines.
A job names its scene by it, so a worker renders exactly that file.

:func:`scene_without_integrator_digest` hashes what a reference integrator
given its own settings sees: the scene as Mitsuba parses it (``-D``
defines substituted, includes read in) without its integrator, and the
bytes of each file a node names. A path reference keyed by it is kept
when only the Whitted settings, a comment, the layout of the XML or an
object's id change; any change to what is rendered gives a new key.
"""

from __future__ import annotations

import hashlib
import json
import re
from pathlib import Path

import mitsuba as mi
import numpy as np

from .scene_files import nodes_naming_files, parse

#: Attributes of a scene file that name other files it depends on.
_FILE_REFERENCE = re.compile(
    r'<string\s+name="filename"\s+value="([^"$]+)"|<include\s+filename="([^"$]+)"')


def named_files(scene_path: Path) -> list[tuple[str, Path]]:
    """Files a scene XML names by a fixed filename: each name as written in
    the scene and the file it resolves to (relative to the scene)."""
    text = Path(scene_path).read_text(errors="replace")
    found = []
    for match in _FILE_REFERENCE.finditer(text):
        name = match.group(1) or match.group(2)
        candidate = (Path(scene_path).parent / name).resolve()
        if candidate.is_file():
            found.append((name, candidate))
    return found


def referenced_files(scene_path: Path) -> list[Path]:
    """Files a scene XML names by a fixed filename (relative to the scene)."""
    return sorted({path for _, path in named_files(scene_path)})


def scene_digest(scene_path: str | Path, defines: dict | None = None) -> str:
    """SHA-256 of a scene file, the files it names and its defines."""
    scene_path = Path(scene_path)
    digest = hashlib.sha256(scene_path.read_bytes())
    for path in referenced_files(scene_path):
        digest.update(path.name.encode())
        digest.update(path.read_bytes())
    digest.update(json.dumps(defines or {}, sort_keys=True).encode())
    return digest.hexdigest()


def scene_without_integrator_digest(scene_path: str | Path, defines: dict | None = None) -> str:
    """SHA-256 of the parsed scene without its integrator, in a canonical
    form, and of the files its nodes name."""
    state = parse(scene_path, defines or {})
    files = {_location(node): _file_digest(candidates)
             for node, candidates in nodes_naming_files(state, scene_path)}
    canonical = _canonical_node(state, state.root, files)
    return hashlib.sha256(json.dumps(canonical, sort_keys=True).encode()).hexdigest()


def _location(node) -> tuple[int, int]:
    """Where a node is written (file and offset): what tells nodes apart."""
    return node.file_index, node.offset


def _file_digest(candidates: list[Path]) -> str | None:
    """SHA-256 of the file Mitsuba reads for a name (the first candidate)."""
    return hashlib.sha256(candidates[0].read_bytes()).hexdigest() if candidates else None


def _canonical_node(state, node, files: dict) -> dict:
    """A node as plain data: its kind, plugin and properties, the objects
    it holds in place of their references, without integrators and ids.
    Unnamed children (``_arg_0``, ...) become a list in the file's order,
    so that removing the integrator shifts no name."""
    props = node.props
    named, unnamed = {}, []
    for key in sorted(props.keys()):
        child = _referenced_node(state, props, key)
        if child is not None and child.type == mi.ObjectType.Integrator:
            continue
        value = (_canonical_node(state, child, files) if child is not None
                 else _canonical_value(props, key))
        if key.startswith("_arg_"):
            unnamed.append((int(key[len("_arg_"):]), value))
        else:
            named[key] = value
    return {"type": str(node.type), "plugin": props.plugin_name(), "properties": named,
            "children": [value for _, value in sorted(unnamed)],
            "file": files.get(_location(node))}


def _referenced_node(state, props, key: str):
    """The node a property refers to (by index or by id), else ``None``."""
    kind = props.type(key)
    if kind == mi.Properties.Type.ResolvedReference:
        return state.nodes[props[key].index()]
    if kind == mi.Properties.Type.Reference:
        return state.nodes[state.id_to_index[props[key].id()]]
    return None


def _canonical_value(props, key: str):
    """A property's value as JSON: numbers at full precision, transforms
    by their matrix, anything else by its text."""
    kind, value = props.type(key), props[key]
    if kind in (mi.Properties.Type.Vector, mi.Properties.Type.Color):
        return [float(component) for component in value]
    if kind == mi.Properties.Type.Transform:
        return np.array(value.matrix, dtype=np.float64).tolist()
    if isinstance(value, (bool, int, float, str)):
        return value
    return repr(value)

"""Scenes as a job names them: by content hash, loadable here or anywhere.

A worker on another machine has no access to this one's files, so a scene
travels as a :class:`SceneBundle`: the XML's bytes, its ``-D`` defines, and
the names of the files it refers to (textures, meshes, includes), each with
the SHA-256 of its content. The contents travel apart, once per job for
each distinct hash, however many scenes share them. The worker rebuilds the
scene's directory layout in a temporary directory, loads the scene from it
and removes it.

The files are the ones :func:`..scene_digest.named_files` finds, the same
that :func:`..scene_digest.scene_digest` covers. A file named by an absolute path
stays where it is: it is read from the worker's own file system.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath

from ..errors import Error
from ..scene_digest import named_files, scene_digest


class SceneShippingError(Error, RuntimeError):
    """A scene that cannot be sent to another process."""


@dataclass(frozen=True)
class SceneBundle:
    name: str                          # the scene file's name
    xml: bytes
    defines: dict
    files: tuple[tuple[str, str], ...]  # (name as written in the scene, SHA-256 of the file)

    @property
    def hashes(self) -> list[str]:
        """The distinct contents the bundle needs, in a fixed order."""
        return sorted({digest for _, digest in self.files})


@dataclass
class SceneSource:
    """A scene file and its defines, identified by :attr:`digest` (the
    :func:`..scene_digest.scene_digest`). ``scene``, when given, is that
    file already loaded in this process, which the in-process backend
    renders instead of loading it again."""

    path: Path | None
    defines: dict = field(default_factory=dict)
    scene: object = None
    digest: str = field(init=False, default="")

    def __post_init__(self):
        if self.path is not None:
            self.path = Path(self.path)
            self.digest = scene_digest(self.path, self.defines)
        else:
            # A scene built in Python: known to this process only.
            self.digest = f"in-memory-{id(self.scene):x}"

    @classmethod
    def loaded(cls, scene) -> "SceneSource":
        """A scene made in this process without a file (``mi.load_dict``)."""
        return cls(None, {}, scene)

    @property
    def label(self) -> str:
        return self.path.name if self.path is not None else "a scene made in Python"

    def load(self):
        from .. import load_file

        return self.scene if self.scene is not None else load_file(self.path, **self.defines)

    def bundle(self) -> tuple[SceneBundle, dict[str, bytes]]:
        """The bundle and the contents it names, by hash."""
        if self.path is None:
            raise SceneShippingError(
                "a scene made in Python has no file to send to other processes; render it "
                "in-process or load it from a scene file.")
        files, contents = [], {}
        for name, path in named_files(self.path):
            if os.path.isabs(name):
                continue
            data = path.read_bytes()
            digest = hashlib.sha256(data).hexdigest()
            contents[digest] = data
            files.append((name, digest))
        bundle = SceneBundle(self.path.name, self.path.read_bytes(), dict(self.defines),
                             tuple(files))
        return bundle, contents


def _levels_up(name: str) -> int:
    """How far above the scene's directory a relative file name reaches."""
    parts = PurePosixPath(os.path.normpath(name).replace(os.sep, "/")).parts
    count = 0
    while count < len(parts) and parts[count] == "..":
        count += 1
    return count


def unpack(bundle: SceneBundle, contents: dict[str, bytes], root: Path) -> Path:
    """Write the scene and its files under ``root`` in their relative
    layout; the path of the scene file written."""
    depth = max((_levels_up(name) for name, _ in bundle.files), default=0)
    scene_dir = root.joinpath(*(f"level{i}" for i in range(depth)))
    scene_dir.mkdir(parents=True, exist_ok=True)
    for name, digest in bundle.files:
        target = Path(os.path.normpath(scene_dir / name))
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(contents[digest])
    scene_path = scene_dir / bundle.name
    scene_path.write_bytes(bundle.xml)
    return scene_path


def load_bundle(bundle: SceneBundle, contents: dict[str, bytes]):
    """The scene of a bundle, loaded from a temporary directory that is
    removed once Mitsuba has read it (textures and meshes are read when
    the scene loads)."""
    from .. import load_file

    with tempfile.TemporaryDirectory(prefix="mitsuba-whitted-") as root:
        return load_file(unpack(bundle, contents, Path(root)), **bundle.defines)

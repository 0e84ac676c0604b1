"""What identifies a scene file: the files it names, and content hashes of
it that both the reference cache and the distributed jobs use.

:func:`scene_digest` hashes the file as written: its bytes, the bytes of
every file it names (textures, meshes, includes) and its ``-D`` defines.
A job names its scene by it, so a worker renders exactly that file.
"""

from __future__ import annotations

import hashlib
import json
import re
from pathlib import Path

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

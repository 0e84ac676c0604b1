"""Reference renders cached on disk under a content hash.

The key covers everything the reference depends on: the scene as its
renderer sees it (:mod:`..scene_digest`), the render settings, and the
Mitsuba version and variant. Editing any of them gives a new key; nothing
else does. Entries are ``.npz`` files
named by the key, written whole or not at all (``files.write_atomically``),
so an interrupted run leaves no half entry behind.
"""

from __future__ import annotations

import hashlib
import json
import warnings
import zipfile
from pathlib import Path

import numpy as np

from ..files import write_atomically


def package_digest() -> str:
    """SHA-256 of this package's Python sources (each file's path and
    bytes): it changes with the code of every plugin."""
    package = Path(__file__).resolve().parents[1]
    digest = hashlib.sha256()
    for path in sorted(package.rglob("*.py")):
        digest.update(path.relative_to(package).as_posix().encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()


def cache_key(**parts) -> str:
    """SHA-256 of the parts (JSON with sorted keys; other objects by
    ``str``) and of the Mitsuba version and variant."""
    import mitsuba as mi

    parts = dict(parts, mitsuba=mi.__version__, variant=mi.variant())
    text = json.dumps(parts, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


class ReferenceCache:
    """A directory of cached arrays; ``hits`` and ``misses`` count lookups."""

    def __init__(self, directory: str | Path):
        self.directory = Path(directory)
        self.hits = 0
        self.misses = 0

    def path(self, key: str) -> Path:
        return self.directory / f"{key}.npz"

    def load(self, key: str) -> dict | None:
        """The entry's arrays; ``None`` if it is absent, or unreadable (cut
        short, or written over by something else), which the next store
        replaces."""
        path = self.path(key)
        if not path.is_file():
            return None
        try:
            with np.load(path) as data:
                return {name: data[name] for name in data.files}
        except (OSError, ValueError, EOFError, zipfile.BadZipFile) as error:
            warnings.warn(f"mitsuba-whitted: the cache entry '{path}' cannot be read "
                          f"({error}); it is computed again.", stacklevel=2)
            return None

    def store(self, key: str, arrays: dict) -> None:
        write_atomically(self.path(key), lambda file: np.savez(file, **arrays))

    def get_or_compute(self, key: str, compute) -> dict:
        """The entry for ``key``, computed by ``compute()`` (a dict of
        arrays) and stored when absent."""
        arrays = self.load(key)
        if arrays is not None:
            self.hits += 1
            return arrays
        self.misses += 1
        arrays = compute()
        self.store(key, arrays)
        return arrays

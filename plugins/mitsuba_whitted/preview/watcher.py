"""Watching the files a scene reads, with ``watchfiles``.

The folders that hold the files are watched, not the files: an editor
that saves by writing a new file and renaming it over the old one
replaces the file a watch would follow. Changes are grouped over
:data:`QUIET_MS` of silence, so that one save (truncate, write, close)
reloads once.
"""

from __future__ import annotations

import os
import threading
from pathlib import Path

import watchfiles

#: Milliseconds without a new change that end a group of changes.
QUIET_MS = 30
#: The longest a group of changes is held back (milliseconds).
LONGEST_MS = 300


class Watcher:
    """Calls ``changed()`` (in a thread of its own) whenever one of the
    files given to :meth:`watch` is written, created, replaced or removed."""

    def __init__(self, changed):
        self.changed = changed
        self._files: frozenset[str] = frozenset()
        self._new_files = threading.Event()
        self._lock = threading.Lock()
        threading.Thread(target=self._run, name="preview watcher", daemon=True).start()

    def watch(self, files) -> None:
        """Watch ``files`` (paths) from now on, in place of the last ones."""
        files = frozenset(os.path.realpath(file) for file in files)
        with self._lock:
            if files != self._files:
                self._files = files
                self._new_files.set()

    def _run(self) -> None:
        while True:
            self._new_files.wait()
            with self._lock:
                files = self._files
                self._new_files.clear()
            folders = sorted({str(Path(file).parent) for file in files
                              if Path(file).parent.is_dir()})
            changes = watchfiles.watch(
                *folders, watch_filter=lambda change, path: path in files,
                stop_event=self._new_files, recursive=False, step=QUIET_MS,
                debounce=LONGEST_MS, rust_timeout=0, ignore_permission_denied=True)
            for _ in changes:
                self.changed()

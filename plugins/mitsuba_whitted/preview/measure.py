"""How long the preview takes from a saved edit to the new image:
``python -m mitsuba_whitted.preview.measure [SCENE] [-D name=value ...]``
starts ``mitsuba-whitted preview`` on a copy of the scene (beside it, so
that its relative file names still hold, removed afterwards), changes the
scene's first ``<rgb>`` value :data:`EDITS` times, and prints the median
time from each save to the change of the status endpoint's generation.
"""

from __future__ import annotations

import json
import os
import re
import signal
import statistics
import subprocess
import sys
import tempfile
import time
import urllib.request
from contextlib import contextmanager
from pathlib import Path

from ..scenes import resolve

EDITS = 10
#: The report's scene (by its shipped name), without anti-aliasing.
DEFAULT = ("cosc363", ["-D", "aa=none"])
#: The first colour of a scene file, which the edits change.
_COLOUR = re.compile(r'(<rgb\s+name="[^"]+"\s+value=")([^"]*)(")')


class Preview:
    """A ``mitsuba-whitted preview`` process and its URL."""

    def __init__(self, process: subprocess.Popen, url: str):
        self.process, self.url = process, url
        self.base, _, self.token = url.partition("/?token=")

    def request(self, path: str, body: dict | None = None, token: bool = True,
                headers: dict | None = None):
        """The answer to GET ``path`` (POST with a JSON ``body``)."""
        data = None if body is None else json.dumps(body).encode()
        address = f"{self.base}{path}" + (f"?token={self.token}" if token else "")
        return urllib.request.urlopen(urllib.request.Request(address, data, headers or {}),
                                      timeout=10)

    def status(self) -> dict:
        return json.load(self.request("/status"))

    def wait(self, condition, timeout: float = 10.0) -> dict:
        """The first status for which ``condition(status)`` holds, polled
        every 2 ms; a ``TimeoutError`` after ``timeout`` seconds."""
        end = time.perf_counter() + timeout
        while time.perf_counter() < end:
            status = self.status()
            if condition(status):
                return status
            time.sleep(0.002)
        raise TimeoutError(f"no such status within {timeout} s; the last: {self.status()}")


@contextmanager
def preview(scene: Path, *arguments: str, cwd=None, env=None):
    """A running ``mitsuba-whitted preview --no-browser --port 0`` of
    ``scene``, ended (Ctrl-C) after the block unless it has ended already."""
    process = subprocess.Popen(
        [sys.executable, "-m", "mitsuba_whitted.cli", "preview", str(scene), "--no-browser",
         "--port", "0", *arguments],
        cwd=cwd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        url = process.stdout.readline().strip()
        if not url:
            raise RuntimeError(f"the preview did not start: {process.stderr.read().strip()}")
        yield Preview(process, url)
    finally:
        if process.poll() is None:
            process.send_signal(signal.SIGINT)
            process.communicate(timeout=30)


def save_to_image(scene: Path, arguments: list[str], edits: int = EDITS) -> list[float]:
    """Seconds from each saved edit of a copy of ``scene`` to its image."""
    text = scene.read_text()
    colour = _COLOUR.search(text)
    if colour is None:
        raise ValueError(f"'{scene}' has no <rgb> value to edit.")
    handle, name = tempfile.mkstemp(".xml", ".preview-measure-", scene.parent)
    os.close(handle)
    copy = Path(name)
    try:
        copy.write_text(text)
        with preview(copy, *arguments) as running:
            status = running.wait(lambda status: status["state"] == "ready", 60)
            times = []
            for edit in range(edits):
                value = colour[2] if edit % 2 else "0.31, 0.32, 0.33"
                changed = text[:colour.start(2)] + value + text[colour.end(2):]
                saved = time.perf_counter()
                copy.write_text(changed)
                status = running.wait(
                    lambda new, seen=status["generation"]: new["generation"] != seen)
                times.append(time.perf_counter() - saved)
                status = running.wait(lambda status: status["state"] == "ready")
                time.sleep(0.2)  # the next save is another one
            return times
    finally:
        copy.unlink(missing_ok=True)


def main(argv: list[str]) -> int:
    name, arguments = (argv[0], argv[1:]) if argv else DEFAULT
    scene = resolve(name)
    times = save_to_image(scene, arguments)
    print(f"{scene} {' '.join(arguments)}: save to new image, median of {len(times)} edits: "
          f"{statistics.median(times):.3f} s (from {min(times):.3f} to {max(times):.3f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

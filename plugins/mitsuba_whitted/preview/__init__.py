"""``mitsuba-whitted preview``: a live view of a scene in the browser.

A local web server (:mod:`.server`) shows the scene as it renders
(:mod:`.session`), first without anti-aliasing, then with the scene's own;
it reloads the scene when its file, an include or a file it names changes
(:mod:`.watcher`), and moves the camera as the page asks (:mod:`.orbit`).
"""

from .server import serve  # noqa: F401

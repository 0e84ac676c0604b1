"""Renders from several Python threads at once: ``mi.render`` (as importing
the package wraps it) and ``whitted``'s own render methods take turns
(:mod:`mitsuba_whitted.render_lock`), so every thread gets the image that
one thread alone renders, and Ctrl-C still reaches the main thread while
it waits for its turn.

Oracles: the images of the same scenes rendered first in the main thread,
one after the other, compared bit for bit; the exception each thread
raised (none)."""

import os
import signal
import sys
import threading

import mitsuba as mi
import numpy as np
import pytest

from mitsuba_whitted import render_lock
from validation.scenes import camera, diffuse, floor, integrator, point_light, scene, sphere

#: Each thread renders this many times, so that renders overlap.
ROUNDS = 3
def description(renderer: dict) -> dict:
    ball = sphere((0, 0, 0), 0.7, diffuse(0.5, 0.2, 0.2))
    return scene(floor(), ball, point_light((2, 3, 4), 30.0),
                 sensor=camera(size=32), integrator=renderer)


def whitted_scene():
    return mi.load_dict(description(integrator(aa="grid", aa_samples=2)))


def path_scene():
    return mi.load_dict(description({"type": "path", "max_depth": 3}))


def image(rendered) -> np.ndarray:
    return np.array(rendered)


@pytest.fixture(scope="module")
def shared():
    """Scenes loaded in the main thread and rendered by several threads."""
    return {"whitted": whitted_scene(), "path": path_scene()}


@pytest.fixture(scope="module")
def expected(shared):
    """Each job's images, rendered in the main thread alone."""
    return {"whitted": image(mi.render(shared["whitted"], seed=3)),
            "path": image(mi.render(shared["path"], seed=3))}


def jobs(shared):
    """What the threads do, each returning (key of the expected image,
    image) for each of its renders."""
    def shared_whitted():
        return "whitted", image(mi.render(shared["whitted"], seed=3))

    def whitted_direct():
        loaded = shared["whitted"]
        return "whitted", image(loaded.integrator().render(loaded, seed=3))

    def shared_path():
        return "path", image(mi.render(shared["path"], seed=3))

    def own_scene():
        # A scene of this thread's, loaded while the others render.
        return "whitted", image(mi.render(whitted_scene(), seed=3))

    return [shared_whitted, shared_whitted, whitted_direct, shared_path, shared_path, own_scene]


def run_together(work) -> tuple[list, list]:
    """Run each of ``work`` ``ROUNDS`` times in a thread of its own, all
    starting at once; their results and their exceptions."""
    start = threading.Barrier(len(work))
    results, errors = [], []

    def thread(job):
        start.wait()
        try:
            for _ in range(ROUNDS):
                results.append(job())
        except Exception as error:  # noqa: BLE001  (reported by the test)
            errors.append(error)

    threads = [threading.Thread(target=thread, args=(job,)) for job in work]
    for started in threads:
        started.start()
    for started in threads:
        started.join()
    return results, errors


def test_threads_rendering_at_once_get_the_single_threaded_images(shared, expected):
    results, errors = run_together(jobs(shared))
    assert errors == []
    assert len(results) == len(jobs(shared)) * ROUNDS
    for key, rendered in results:
        np.testing.assert_array_equal(rendered, expected[key], err_msg=f"image {key!r}")


def waiting_for_the_lock(thread: threading.Thread) -> bool:
    """Whether ``thread`` sleeps waiting for the render lock (a signal that
    came just before it went to sleep would be handled only after its wait)."""
    frame = sys._current_frames().get(thread.ident)
    if frame is None or frame.f_code is not render_lock._holding.__wrapped__.__code__:
        return False
    with open(f"/proc/self/task/{thread.native_id}/stat") as stat:
        return stat.read().rpartition(")")[2].split()[0] == "S"


def test_ctrl_c_while_another_thread_renders_reaches_the_main_thread(shared, expected):
    """The main thread waits for its turn while a worker's render holds the
    lock (in its progress display); a real SIGINT then interrupts the wait
    at once: the worker is still rendering when the interrupt arrives."""
    # A render of Mitsuba's own integrator first: it leaves SIGINT restarting
    # the waits it interrupts.
    mi.render(shared["path"], seed=3)
    worker_scene = whitted_scene()
    rendering, go_on = threading.Event(), threading.Event()

    def hold(*progress):
        rendering.set()
        go_on.wait(timeout=60)

    worker_scene.integrator().progress = hold
    worker_images = []
    worker = threading.Thread(target=lambda: worker_images.append(
        image(mi.render(worker_scene, seed=3))))

    def interrupt_the_wait():
        rendering.wait()
        while not waiting_for_the_lock(threading.main_thread()):
            threading.Event().wait(0.01)
        os.kill(os.getpid(), signal.SIGINT)

    worker.start()
    rendering.wait()
    threading.Thread(target=interrupt_the_wait, daemon=True).start()
    try:
        with pytest.raises(KeyboardInterrupt):
            mi.render(shared["whitted"], seed=3)
        assert not go_on.is_set() and worker.is_alive()
    finally:
        go_on.set()
        worker.join()
    np.testing.assert_array_equal(worker_images[0], expected["whitted"])
    np.testing.assert_array_equal(image(mi.render(shared["whitted"], seed=3)),
                                  expected["whitted"])

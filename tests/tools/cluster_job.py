"""Reference jobs on a running Ray cluster, for tests/test_cluster.py.

Run in a process of its own (Ray's driver state and its token settings stay
out of the test process):

    python tests/tools/cluster_job.py ADDRESS workers SCENE RES SPP OUT.npz
        references of SCENE rendered with 1, 2 and 16 tasks in flight
    python tests/tools/cluster_job.py ADDRESS interrupt SCENE RES SPP CACHE_DIR
        a cached reference, all 16 tasks in flight, stopped by Ctrl-C after
        its first task ends; then the same reference twice more; prints
        what happened as JSON
"""

import json
import sys
from pathlib import Path

import numpy as np

import mitsuba_whitted
from mitsuba_whitted.compare import ReferenceCache, cached_reference, render_reference
from mitsuba_whitted.distributed import SceneSource
from mitsuba_whitted.distributed.ray_backend import RayBackend

#: Seconds to wait for a cancelled task's outcome.
CANCEL_SECONDS = 60


def worker_counts(address, source, spp, out):
    arrays = {}
    with RayBackend.start(None, address):
        for workers in (1, 2, 16):
            reference = render_reference(source, spp, backend=RayBackend(workers, address))
            arrays[f"image_{workers}"] = reference.image
            arrays[f"variance_{workers}"] = reference.variance
    np.savez(out, **arrays)


def interrupt(address, source, spp, cache_dir):
    import ray

    def ctrl_c(done, total, what):
        raise KeyboardInterrupt

    cache = ReferenceCache(cache_dir)
    report = {}
    with RayBackend.start(None, address):
        # Every task in flight: most are still queued when the first ends.
        backend = RayBackend(16, address)
        try:
            cached_reference(cache, "key", source, spp, progress=ctrl_c, backend=backend)
        except KeyboardInterrupt:
            report["interrupted"] = True
        report["cancelled"] = [_outcome(ray, ref) for ref in backend.cancelled]
        report["entries_after_interrupt"] = sorted(p.name for p in Path(cache_dir).iterdir())
        before = backend.tasks_run
        cached_reference(cache, "key", source, spp, backend=backend)
        report["tasks_of_second_run"] = backend.tasks_run - before
        before = backend.tasks_run
        third = cached_reference(cache, "key", source, spp, backend=backend)
        report["tasks_of_third_run"] = backend.tasks_run - before
        report["third_cached"] = third.cached
    report["entries"] = sorted(p.name for p in Path(cache_dir).iterdir())
    print(json.dumps(report))


def _outcome(ray, ref) -> str:
    try:
        ray.get(ref, timeout=CANCEL_SECONDS)
    except ray.exceptions.TaskCancelledError:
        return "cancelled"
    except ray.exceptions.RayError as error:
        return type(error).__name__
    return "finished"


def main(address, mode, scene, res, spp, out):
    mitsuba_whitted.set_variant("llvm_ad_rgb")
    source = SceneSource(scene, {"res": res})
    {"workers": worker_counts, "interrupt": interrupt}[mode](address, source, int(spp), out)


if __name__ == "__main__":
    main(*sys.argv[1:])

"""Render two glass spheres one behind the other and print peak RSS (MiB).

Run in a fresh process so the figure is this render's own:
    python tests/tools/memory_probe.py SIZE MAX_DEPTH
"""

import json
import sys
import time

import mitsuba_whitted
import drjit as dr
import mitsuba as mi


def main(size: int, max_depth: int) -> None:
    mitsuba_whitted.set_variant("llvm_ad_rgb")
    from mitsuba_whitted.bench.processes import peak_rss_mib
    glass = {"type": "dielectric", "int_ior": 1.5}
    scene = mi.load_dict({
        "type": "scene",
        "sensor": {"type": "perspective", "fov": 35,
                   "to_world": mi.ScalarTransform4f().look_at([0, 0, 6], [0, 0, 0], [0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": size, "height": size}},
        "front": {"type": "sphere", "center": [0, 0, 1.2], "radius": 1.0, "bsdf": glass},
        "back": {"type": "sphere", "center": [0, 0, -1.2], "radius": 1.0, "bsdf": glass},
        "env": {"type": "constant", "radiance": {"type": "rgb", "value": [0.8, 0.9, 1.0]}},
        "light": {"type": "point", "position": [2, 3, 4], "intensity": {"type": "rgb", "value": 30}},
    })
    integrator = mi.load_dict({"type": "whitted", "max_depth": max_depth})
    start = time.perf_counter()
    image = mi.render(scene, integrator=integrator)
    dr.sync_thread()
    seconds = time.perf_counter() - start
    finite = bool(dr.all(dr.isfinite(image.array)))
    peak = peak_rss_mib()
    print(json.dumps({"peak_rss_mib": peak, "seconds": seconds, "finite": finite,
                      "rays": integrator.last_stats}))


if __name__ == "__main__":
    main(int(sys.argv[1]), int(sys.argv[2]))

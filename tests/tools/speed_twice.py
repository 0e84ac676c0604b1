"""The report's speed section measured twice, small, in a process of its
own, as ``validation.run`` measures it; for tests/test_speed.py:

    python tests/tools/speed_twice.py CACHE_DIR OUT.json

writes, for each run and each scene in the section's order, every speed-up
of the scene (by setting and metric, and the family's by error level) as
``[key, median, low, high]``.
"""

import json
import sys

import mitsuba_whitted
from mitsuba_whitted.compare import ReferenceCache
from validation.run import SpeedSettings, measure_speed


def speedups(comparison) -> list:
    """Every Whitted setting's speed-up in every metric, and the family's
    at every error level."""
    results = comparison.results
    rows = [[f"{label}, {metric}", entry.speedup[metric]]
            for label, entry in results.whitted.items() for metric in results.metrics]
    rows += [[f"level {entry.error:g}", entry.speedup] for entry in results.levels.entries
             if entry.speedup is not None]
    return [[key, s.median, s.low, s.high] for key, s in rows]


def main(cache_dir: str, out: str) -> None:
    mitsuba_whitted.set_variant("llvm_ad_rgb")
    cache = ReferenceCache(cache_dir)
    runs = [measure_speed(SpeedSettings.quick(), cache, None) for _ in range(2)]
    with open(out, "w") as file:
        json.dump([{c.name: speedups(c) for c in run} for run in runs], file)


if __name__ == "__main__":
    main(*sys.argv[1:])

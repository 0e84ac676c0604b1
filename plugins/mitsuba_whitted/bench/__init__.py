"""``mitsuba-whitted bench``: speed, throughput bound, memory and scaling,
measured side by side in one run.

Every timed JIT computation ends with ``dr.sync_thread()`` before the clock
stops. Warm figures are medians over repeated renders in one process, each
with its 95% interval (a bootstrap over the renders); the first render of a fresh process (tracing and compiling, or loading compiled
kernels from Dr.Jit's cache) is measured in child processes, once with the
kernel cache as it is and once with an empty one.

- :mod:`.timing`: render times in this process, and their scaling with
  resolution and depth;
- :mod:`.bound`: the ray-casting bound (the render's own rays through
  Mitsuba's ray casting) and the split of a render at its first launch;
- :mod:`.processes`: fresh processes and their peak memory;
- :mod:`.equal_error`: the equal-error speed-up over ``path``, timed in
  interleaved rounds as ``compare`` times it;
- :mod:`.gradient_figures`: the time and memory of a gradient, and its error
  against ``prb``'s at equal time;
- :mod:`.suite`: the settings and the run of all of them;
- :mod:`.results`: the figures as dataclasses, and their JSON;
- :mod:`.tables`: the figures as a table.
"""

from .results import BenchResults, results_json
from .suite import DEFAULT_SCENE, BenchSettings, run
from .tables import format_table

__all__ = ["DEFAULT_SCENE", "BenchResults", "BenchSettings", "format_table", "results_json",
           "run"]

"""Rendering many tasks on one machine or a Ray cluster, with the same bits.

A job is a list of :class:`Task` objects (a scene by content hash, a sample
seed, samples per pixel, an integrator) and the :class:`SceneSource` of
each scene; a backend (:func:`backend`) renders them in this process or on
Ray. Whatever the backend and its number of workers, and whether or not
Ray had to run a task again after a worker died, each task's image is the
one Mitsuba renders for it here, and results that are combined are
combined in the job's order (:func:`in_order`), so the final images are
identical bit for bit.

That holds where Mitsuba's render is itself repeatable: with a ``box``
reconstruction filter (every scene of this package). With a wider filter,
Mitsuba's LLVM film adds each sample into several pixels with atomic adds
whose order changes from run to run, even in one process (last bits of
about 1e-6 relative).
"""

from ..errors import ClusterError
from .backends import InProcess, backend, in_order, run_job
from .scene import SceneBundle, SceneShippingError, SceneSource
from .task import Environment, Task

__all__ = ["ClusterError", "Environment", "InProcess", "SceneBundle", "SceneShippingError",
           "SceneSource", "Task", "backend", "in_order", "run_job"]

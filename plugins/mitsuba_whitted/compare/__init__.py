"""Comparing the Whitted integrator with Mitsuba's path tracer: error
metrics, the per-pixel equivalence test, reference renders and their cache,
the speed-against-error sweep, and the report writer."""

from .cache import ReferenceCache, cache_key, scene_digest
from .equivalence import (EquivalenceResult, equivalence_test, path_batches, t_quantile,
                          whitted_batches)
from .metrics import (flip_error, luminance, missing_energy_share, missing_light, noise_rel_mse,
                      rel_mse, rel_squared_error, rmse)
from .reference import Reference, cached_reference, path_settings, render_reference
from .sweep import (SweepPoint, crossing, equal_error, path_spp_ladder, run_sweep,
                    scene_whitted_settings, speedups, timed_render, whitted_variants)
from .scene_report import CompareError, CompareOptions, compare_scene, load_scene

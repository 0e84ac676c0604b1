"""Comparing the Whitted integrator with Mitsuba's path tracer: error
metrics, the per-pixel equivalence test, reference renders and their cache,
the speed-against-error sweep with its intervals and verdicts, Whitted's
converged renders, and the report writer."""

from .cache import ReferenceCache, cache_key
from .equivalence import (EquivalenceResult, equivalence_test, path_batches, t_quantile,
                          whitted_batches)
from .metrics import (error_maps, flip_error, luminance, missing_energy_share, missing_light,
                      noise_rel_mse, rel_mse, rel_squared_error, rmse)
from .reference import Reference, cached_reference, path_settings, render_reference
from .sweep import (PATH_SAMPLERS, Setting, Sweep, SweepPoint, path_ladder, path_spp_ladder,
                    run_sweep, scene_whitted_settings, whitted_settings, whitted_variants)
from .equal_error import Analysis, Gain, analyse, envelope, reach
from .intervals import Estimate, estimate_text, verdict, verdict_text
from .scene_report import (CompareError, CompareOptions, SceneComparison, check_report_folder,
                           compare_scene, load_scene, loaded_source, measure_scene,
                           write_scene_report)

"""The bench's figures as typed data, which the tables read and
``--json`` writes (:func:`results_json`)."""

from __future__ import annotations

from dataclasses import dataclass

from ..compare.intervals import json_data
from .bound import Bound, LaunchSplit
from .equal_error import EqualErrorFigures
from .gradient_figures import GradientFigures
from .processes import ProcessTiming
from .timing import RenderTiming, ScalingRow


@dataclass
class Headline:
    """The scene's own figures: its renders, rays and ray-casting bound.
    ``bound`` and ``split`` are ``None`` where ``not_measured`` says why."""

    scene: str
    defines: dict
    settings: dict
    resolution: list
    indirect_samples: int
    timing: RenderTiming
    rays: dict
    rays_per_second: float
    bound: Bound | None
    split: LaunchSplit | None
    not_measured: dict
    peak_rss_mib_this_process: float


@dataclass
class BenchResults:
    """Every figure of a bench run; :func:`results_json` writes it out.
    The fresh-process figures are ``None`` where they were not measured."""

    machine: str
    headline: Headline
    fresh_process: ProcessTiming | None
    fresh_process_empty_cache: ProcessTiming | None
    peak_rss_mib: dict
    scaling: list[ScalingRow]
    equal_error: EqualErrorFigures
    gradient: GradientFigures


def results_json(results: BenchResults) -> dict:
    """The figures as JSON data (an infinite bound of an interval ``None``)."""
    return json_data(results)

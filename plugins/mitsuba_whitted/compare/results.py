"""A comparison's figures as typed data. The report reads them by
attribute; ``results.json`` is :func:`~.intervals.json_data` of them, with
the keys the README describes (section *Speed against error*)."""

from __future__ import annotations

from dataclasses import dataclass

from .equal_error import Gain
from .intervals import Estimate, verdict
from .levels import GoalSummary, Level


@dataclass
class PhotonFigures:
    """The reference's photon part: photons per pass, passes per run,
    independent runs, its render time, whether it came from the cache, its
    own noise (relMSE) and the gather radius of a run's first and last
    passes (scene units)."""

    photons: int
    passes: int
    runs: int
    seconds: float
    cached: bool
    noise_rel_mse: float
    radius_first: float
    radius_last: float


@dataclass
class ReferenceFigures:
    """The reference: ``name`` says which it is (``path``, or ``path +
    photons (N photons x P passes)``); ``seconds`` and ``noise_rel_mse``
    are of the whole of it; ``path_floor_rel_mse``, path's own error
    against it (0 where it is path alone); ``photons``, its photon part
    (``None`` where it has none)."""

    spp: int
    passes: int
    seconds: float
    cached: bool
    noise_rel_mse: float
    size: list
    name: str = "path"
    path_floor_rel_mse: float = 0.0
    photons: PhotonFigures | None = None


@dataclass
class TimingFigures:
    rounds: int
    replicates: int
    seed: int
    tiles: dict
    interval: float


@dataclass
class ConvergedRender:
    settings: dict
    seconds: float
    cached: bool


@dataclass
class ConvergedFigures:
    side: int
    renders: list[ConvergedRender]


@dataclass
class PathThere:
    """Path's time and samples per pixel at an error, and the sampler whose
    curve reaches it first."""

    seconds: Estimate
    spp: Estimate
    sampler: str


@dataclass
class PointFigures:
    """A render of the sweep: its times and errors, and the name of its
    image where the report shows it (else ``None``)."""

    first_seconds: float
    image: str | None
    seconds: Estimate
    rel_mse: float
    rmse: float
    flip: float | None

    def total(self, metric: str) -> float:
        """The render's error in ``metric``."""
        return self.rel_mse if metric == "relmse" else self.flip


@dataclass
class PathRung(PointFigures):
    spp: int


@dataclass
class WhittedFigures(PointFigures):
    """A Whitted setting: its error split into sampling error and model
    bias, and, by metric, its speed-up over path, the verdict and path's
    figures at its error."""

    settings: dict
    sampling_error: dict
    model_bias: dict
    speedup: dict[str, Estimate]
    verdict: dict[str, str]
    path_at_equal_error: dict[str, PathThere]


def gain_fields(gains: dict[str, Gain]) -> dict:
    """A setting's gains by metric, as :class:`WhittedFigures` fields."""
    return {"speedup": {m: g.speedup for m, g in gains.items()},
            "verdict": {m: verdict(g.speedup) for m, g in gains.items()},
            "path_at_equal_error": {m: PathThere(g.path_seconds, g.path_spp, g.sampler)
                                    for m, g in gains.items()}}


@dataclass
class Crossing:
    """Where path overtakes the most accurate Whitted setting (``label``)."""

    label: str
    path_seconds: Estimate
    path_spp: Estimate
    sampler: str


@dataclass
class FamilyThere:
    """The Whitted family at an error level: the time of the cheapest
    setting that reaches it (``setting`` ``None`` where none does), and the
    indirect paths per pixel where a ladder gives it."""

    seconds: Estimate
    setting: str | None
    paths: float | None


@dataclass
class LevelEntry:
    error: float
    path: PathThere
    whitted: FamilyThere
    speedup: Estimate | None
    verdict: str
    goal: str
    path_reaches: bool = True

    @classmethod
    def of(cls, level: Level) -> "LevelEntry":
        return cls(level.error, PathThere(level.path, level.path_spp, level.sampler),
                   FamilyThere(level.whitted, level.setting, level.paths), level.speedup,
                   level.verdict, level.goal, level.path_reaches)


@dataclass
class LevelsFigures:
    """The levels; ``path_floor``: the relMSE below which path never
    gets, the levels there marked so (0: none)."""

    metric: str
    top: float
    noise_multiple: float
    entries: list[LevelEntry]
    summary: GoalSummary
    path_floor: float = 0.0


@dataclass
class CompareResults:
    """Every number of a comparison's report. ``whitted`` and ``path`` keep
    the report's order."""

    scene: str
    reference: ReferenceFigures
    metrics: list
    timing: TimingFigures
    converged: ConvergedFigures
    whitted: dict[str, WhittedFigures]
    path: dict[str, list[PathRung]]
    levels: LevelsFigures
    crossing: dict[str, Crossing]
    missing_energy_share: float
    film_filter: str

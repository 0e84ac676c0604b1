"""Speed against error, measured for real: its intervals hold from one run
to the next, and a tie built on purpose is called a tie.

The renders are small (32 to 96 pixels) so that the whole takes well under
a minute; the assertions are the ones the intervals exist for, not
timings."""

from mitsuba_whitted.compare import (Estimate, ReferenceCache, Setting, analyse, load_scene,
                                     path_ladder, path_settings, render_reference, run_sweep,
                                     verdict, verdict_text)
from mitsuba_whitted.compare.report import MarkdownReport
from mitsuba_whitted.compare.sweep import sampler_sensors
from validation.run import SpeedSettings, speed_section
from validation.scenes import SPEED


def _speedups(comparison) -> dict:
    """Every Whitted setting's speed-up in every metric, by (label, metric),
    and the family's at every error level, by level."""
    speedups = {(label, metric): Estimate.from_json(entry["speedup"][metric])
                for label, entry in comparison.results["whitted"].items()
                for metric in comparison.results["metrics"]}
    speedups.update({("level", entry["error"]): Estimate.from_json(entry["speedup"])
                     for entry in comparison.results["levels"]["entries"]
                     if entry["speedup"] is not None})
    return speedups


def test_two_runs_of_the_speed_section_agree(tmp_path):
    """The report's speed section twice on its own scenes, small: each
    interval of the second run overlaps the first's, the family's speed-up
    at each error level too."""
    cache = ReferenceCache(tmp_path / "cache")
    runs = [speed_section(MarkdownReport(tmp_path / f"run{index}", "speed"), cache, None,
                          SpeedSettings.quick())
            for index in range(2)]
    assert [c.name for c in runs[0]] == [path.stem for path in SPEED]
    for first, second in zip(*runs):
        again = _speedups(second)
        for key, estimate in _speedups(first).items():
            assert max(estimate.low, again[key].low) <= min(estimate.high, again[key].high), (
                f"{first.name}, {key}: {verdict_text(estimate)} then {verdict_text(again[key])}")


def test_path_against_itself_is_a_tie():
    """A 'Whitted' setting that is path at 4 spp with another seed, against
    path's own ladder: the same work for the same error, so neither
    metric may call it faster or slower."""
    scene_path, defines = SPEED[1], {"res": "96"}
    scene = load_scene(scene_path, defines)
    reference = render_reference(scene, 256)
    sensors = sampler_sensors(scene_path, defines, ("independent",))
    itself = Setting("path 4 spp, another seed", "whitted", path_settings(), 4, "independent",
                     seed=99)
    sweep = run_sweep(scene, reference, [itself] + path_ladder(16, ("independent",)), sensors,
                      rounds=5)
    gains = analyse(sweep).gains[itself.label]
    assert {metric: verdict(g.speedup) for metric, g in gains.items()} == {
        "relmse": "tie", "flip": "tie"}, {m: verdict_text(g.speedup) for m, g in gains.items()}

"""Speed against error, measured for real: its intervals hold from one run
to the next, and a tie built on purpose is called a tie.

The renders are small (32 to 96 pixels) so that the whole takes well under
a minute; the assertions are the ones the intervals exist for, not
timings."""

import json

from mitsuba_whitted.compare import (ReferenceCache, Setting, analyse, load_scene,
                                     path_ladder, path_settings, render_reference, run_sweep,
                                     verdict, verdict_text)
from mitsuba_whitted.compare.intervals import json_data
from mitsuba_whitted.compare.report import MarkdownReport
from mitsuba_whitted.compare.sweep import sampler_sensors
from validation.run import SpeedSettings, measure_speed, write_speed_section
from validation.scenes import SPEED


def _speedups(comparison) -> dict:
    """Every Whitted setting's speed-up in every metric, by (label, metric),
    and the family's at every error level, by level."""
    speedups = {(label, metric): entry.speedup[metric]
                for label, entry in comparison.results.whitted.items()
                for metric in comparison.results.metrics}
    speedups.update({("level", entry.error): entry.speedup
                     for entry in comparison.results.levels.entries
                     if entry.speedup is not None})
    return speedups


def test_two_runs_of_the_speed_section_agree(tmp_path):
    """The report's speed section measured twice on its own scenes, small
    (without writing its report, which reads only these results): each
    interval of the second run overlaps the first's, the family's speed-up
    at each error level too."""
    cache = ReferenceCache(tmp_path / "cache")
    runs = [measure_speed(SpeedSettings.quick(), cache, None) for _ in range(2)]
    _check_written_section(tmp_path / "report", runs[1][0])
    assert [c.name for c in runs[0]] == [path.stem for path in SPEED]
    for first, second in zip(*runs):
        again = _speedups(second)
        for key, estimate in _speedups(first).items():
            assert max(estimate.low, again[key].low) <= min(estimate.high, again[key].high), (
                f"{first.name}, {key}: {verdict_text(estimate)} then {verdict_text(again[key])}")


def _check_written_section(folder, comparison):
    """The section written for one measured scene: its report beside it,
    holding exactly the measured results, and a row in the goal table."""
    report = MarkdownReport(folder, "speed")
    write_speed_section(report, SpeedSettings.quick(), [comparison])
    text = "\n".join(report.lines)
    scene_folder = folder / "speed" / comparison.name
    assert comparison.report == scene_folder / "report.md" and comparison.report.is_file()
    written = json.loads((scene_folder / "results.json").read_text())
    assert written == json.loads(json.dumps(json_data(comparison.results)))
    assert f"(speed/{comparison.name}/report.md)" in text and "3.0 The goal" in text
    assert (scene_folder / "images" / "speed_vs_error.png").is_file()


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

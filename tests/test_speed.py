"""Speed against error, measured for real: its intervals hold from one run
to the next, and a tie built on purpose is called a tie.

The renders are small (32 to 96 pixels) so that the whole takes well under
a minute; the assertions are the ones the intervals exist for, not
timings."""

import dataclasses
import json
import os
import subprocess
import sys

from mitsuba_whitted.compare import (ReferenceCache, Setting, analyse, load_scene,
                                     path_ladder, path_settings, render_reference, run_sweep,
                                     verdict, verdict_text)
from mitsuba_whitted.compare.intervals import json_data
from mitsuba_whitted.compare.report import MarkdownReport
from mitsuba_whitted.compare.sweep import sampler_sensors
from validation.run import SpeedSettings, measure_speed, write_speed_section
from validation.scenes import ROOT, SPEED


def test_two_runs_of_the_speed_section_agree(tmp_path):
    """The report's speed section measured twice on its own scenes, small,
    in a fresh process as ``validation.run`` measures it: each interval of
    the second run overlaps the first's, the family's speed-up at each
    error level too."""
    out = tmp_path / "speedups.json"
    # The tool imports validation/, which is on the tests' path, not on a child's.
    path = os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))
    subprocess.run([sys.executable, str(ROOT / "tests" / "tools" / "speed_twice.py"),
                    str(tmp_path / "cache"), str(out)], check=True, timeout=600, cwd=ROOT,
                   env=dict(os.environ, PYTHONPATH=path))
    first, second = json.loads(out.read_text())
    assert list(first) == list(second) == [path.stem for path in SPEED]
    for scene in first:
        again = {key: (low, high) for key, _, low, high in second[scene]}
        assert again.keys() == {key for key, *_ in first[scene]}
        for key, median, low, high in first[scene]:
            assert max(low, again[key][0]) <= min(high, again[key][1]), (
                f"{scene}, {key}: {median:.3g}x ({low:.3g}-{high:.3g}) then "
                f"({again[key][0]:.3g}-{again[key][1]:.3g})")


def test_the_section_holds_what_was_measured(tmp_path):
    """The section written for a measured scene: its report beside it,
    holding exactly the measured results, and a row in the goal table."""
    settings = dataclasses.replace(SpeedSettings.quick(), scenes=SPEED[:1])
    comparison, = measure_speed(settings, ReferenceCache(tmp_path / "cache"), None)
    folder = tmp_path / "report"
    report = MarkdownReport(folder, "speed")
    write_speed_section(report, settings, [comparison])
    text = "\n".join(report.lines)
    scene_folder = folder / "speed" / comparison.name
    assert comparison.report == scene_folder / "report.md" and comparison.report.is_file()
    written = json.loads((scene_folder / "results.json").read_text())
    assert written == json.loads(json.dumps(json_data(comparison.results)))
    assert f"(speed/{comparison.name}/report.md)" in text and "3.0 The goal" in text
    assert (scene_folder / "images" / "speed_vs_error.png").is_file()
    # Its page too, linked from the section (tests/test_viewer.py opens one).
    assert (scene_folder / "index.html").is_file()
    assert f"(speed/{comparison.name}/index.html)" in text


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

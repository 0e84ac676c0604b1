"""One progress report for a whole render, however many bands and
anti-aliasing levels it takes.

The camera shader reports each call it traces (a run of grid pixels, an
adaptive level, a contrast pass) from 0 to that call's own size: shown as
they come, a bar would start again at 0 for every band and every level, and
its time left would be that of the call. Here the render is one task of a
fixed size, counted in the samples of each band's first pass (which the
pattern sizes before it traces anything) and one step for each refinement
level a band may take after it (their sizes depend on what the levels
before them saw, so they cannot be counted ahead). A band that stops
refining early jumps to its end: the count only grows, and a finished
render is at its total.
"""

from __future__ import annotations

#: What the progress display calls a render.
LABEL = "rendering"


class RenderProgress:
    """Hands ``progress(done, total, LABEL)`` the render's count as the
    camera shader reports its calls to :meth:`traced`; ``progress`` may be
    ``None`` (nothing is reported). ``sampler`` says how many samples a
    band's first pass traces (``first_pass_samples(band)``) and how many
    refinement levels may follow (``refinement_levels``; see
    :mod:`.antialias`). The display hears ``(0, total)`` at once, so that its
    clock, and with it the time left, starts with the render."""

    def __init__(self, progress, sampler, bands: list):
        self.progress = progress
        self.sampler = sampler
        self.total = (sum(sampler.first_pass_samples(band) for band in bands)
                      + sampler.refinement_levels * len(bands))
        self.done = 0
        #: The count once the band being rendered is finished.
        self.band_end = 0
        #: Samples of that band's first pass not traced yet.
        self.first_pass_left = 0
        #: Samples of the shader's current call already counted.
        self.call_done = 0
        self._report()

    def start_band(self, band) -> None:
        self.first_pass_left = self.sampler.first_pass_samples(band)
        self.band_end += self.first_pass_left + self.sampler.refinement_levels

    def end_band(self) -> None:
        """The band is finished: the levels it did not take are skipped."""
        self._advance_to(self.band_end)

    def traced(self, done: int, total: int) -> None:
        """The shader's report of a call: ``done`` of its ``total`` samples
        traced, ``done == total`` once, at the call's end. First-pass
        samples count one by one; a later call (a refinement level) counts
        one step when it ends."""
        new = done - self.call_done
        self.call_done = 0 if done == total else done
        if self.first_pass_left:
            counted = min(new, self.first_pass_left)
            self.first_pass_left -= counted
            self._advance_to(self.done + counted)
        elif done == total:
            self._advance_to(min(self.done + 1, self.band_end))

    def _advance_to(self, done: int) -> None:
        if done > self.done:
            self.done = done
            self._report()

    def _report(self) -> None:
        if self.progress is not None:
            self.progress(self.done, self.total, LABEL)

"""The inverse-rendering example of :mod:`validation.inverse_texture` with
Mitsuba's ``prb``: the same scene, the same grey start and Adam, the target
rendered by ``prb`` itself with 1024 samples per pixel, and each gradient
estimated from 16 (a new seed every iteration).

    python -m validation.inverse_texture_prb [--iterations N] [--out DIR]
"""

from __future__ import annotations

import sys

from mitsuba_whitted.command import run_command
from validation.inverse_texture import main


def prb_integrator() -> dict:
    return {"type": "prb", "max_depth": 6}


if __name__ == "__main__":
    PROGRAM = "validation.inverse_texture_prb"
    sys.exit(run_command(lambda: main(name="prb", integrator=prb_integrator, spp=16,
                                      target_spp=1024, program=PROGRAM), program=PROGRAM))

"""Peak memory of a deep glass render, measured in a fresh process."""

import json
import subprocess
import sys
from pathlib import Path

PROBE = Path(__file__).parent / "tools" / "memory_probe.py"
LIMIT_MIB = 4096


def test_two_glass_spheres_depth_24_at_1024_stays_under_4_gib():
    output = subprocess.run([sys.executable, str(PROBE), "1024", "24"], check=True,
                            capture_output=True, text=True, timeout=600).stdout
    result = json.loads(output.strip().splitlines()[-1])
    assert result["finite"]
    # The ray tree really is deep: glass gives many generations of rays.
    assert result["rays"]["generations"] >= 12
    assert result["rays"]["refraction"] > 4 * 1024 * 1024
    assert result["peak_rss_mib"] < LIMIT_MIB, result

"""What the machine says about itself, where Linux says it."""

from __future__ import annotations


def proc_field(path: str, name: str) -> str | None:
    """The value of the ``name:`` line of a ``/proc`` file (``/proc/cpuinfo``,
    ``/proc/self/status``), or ``None`` where the system has no such file or
    line."""
    try:
        with open(path) as lines:
            for line in lines:
                key, _, value = line.partition(":")
                if key.strip() == name:
                    return value.strip()
    except OSError:
        pass
    return None

"""What the machine says about itself (where Linux says it), the versions
timings depend on, and how this interpreter runs the package's programs in
child processes."""

from __future__ import annotations

import codecs
import os
import platform
import sys
from pathlib import Path


def program_command(program: str, *args: str) -> list[str]:
    """The command line that runs ``program`` (a file of
    :mod:`mitsuba_whitted.programs`, without ``.py``) with ``args`` in this
    interpreter."""
    folder = Path(__file__).with_name("programs")
    return [sys.executable, str(folder / f"{program}.py"), *args]


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


def machine() -> str:
    """The processor, the system, the core count and the versions that
    timings depend on, in one line."""
    # Imported here: files.py, which llvm.py needs, imports this module
    # before the libLLVM is chosen, and Dr.Jit loads one when imported.
    import drjit as dr
    import mitsuba as mi
    return (f"{platform.machine()} ({_cpu_model()}), {platform.system()} {platform.release()}, "
            f"{_cpu_count()} CPU cores; Python {platform.python_version()}, "
            f"mitsuba {mi.__version__}, drjit {dr.__version__}, variant {mi.variant()}")


def _cpu_model() -> str:
    """The processor's name (Linux), which timings depend on as much as on
    the core count; "unknown CPU" where the system does not say."""
    return proc_field("/proc/cpuinfo", "model name") or "unknown CPU"


def _cpu_count() -> int:
    """The cores this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()


MEMINFO = "/proc/meminfo"
#: Where a cgroup (v2, then v1) states the memory its processes may use.
CGROUP_LIMITS = (("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory.current"),
                 ("/sys/fs/cgroup/memory/memory.limit_in_bytes",
                  "/sys/fs/cgroup/memory/memory.usage_in_bytes"))


def available_memory() -> int | None:
    """Bytes this process can still allocate: the kernel's estimate of
    memory available without swapping (``MemAvailable``), or less where a
    cgroup limit or the address-space limit (``ulimit -v``) leaves less.
    ``None`` where Linux does not say."""
    available = proc_field(MEMINFO, "MemAvailable")  # "1234 kB"
    candidates = [int(available.split()[0]) * 1024] if available else []
    for limit_path, usage_path in CGROUP_LIMITS:
        limit, usage = _read_int(limit_path), _read_int(usage_path)
        if limit is not None and usage is not None:
            candidates.append(max(limit - usage, 0))
            break
    left = address_space_left()
    if left is not None:
        candidates.append(left)
    return min(candidates) if candidates else None


def available_text(available: int) -> str:
    """What a sentence says of ``available`` bytes (see
    :func:`available_memory`), naming the address-space limit where there
    is one: a process under it can have far less than the machine has."""
    limit = address_space_limit()
    under = f" under {describe_limit(limit)}" if limit is not None else ""
    return f"{size_text(available)} of memory are available{under}"


def address_space_limit() -> int | None:
    """The process's address-space limit in bytes (``ulimit -v``, which
    counts every mapping: libraries, thread stacks, memory reserved and not
    yet used), or ``None`` where there is none."""
    import resource

    limit = resource.getrlimit(resource.RLIMIT_AS)[0]
    return None if limit == resource.RLIM_INFINITY else limit


def address_space_left() -> int | None:
    """Bytes of address space the process can still map under its limit
    (``None`` where there is no limit, or Linux does not say): what a
    failed allocation there ends in is not always an exception (a Dr.Jit
    worker thread's segmentation fault)."""
    limit = address_space_limit()
    mapped = proc_field("/proc/self/status", "VmSize")  # "1234 kB"
    if limit is None or mapped is None:
        return None
    return max(limit - int(mapped.split()[0]) * 1024, 0)


def describe_limit(limit: int) -> str:
    """The address-space limit as a sentence names it, also as ``ulimit
    -v`` takes it (in KiB)."""
    return f"the address-space limit of {size_text(limit)} (ulimit -v {limit >> 10})"


def size_text(size: int) -> str:
    """A size in bytes as a sentence says it: "3.0 MiB", "832 MiB", "112 GiB"."""
    for unit, scale in (("GiB", 1 << 30), ("MiB", 1 << 20), ("KiB", 1 << 10)):
        if size >= scale:
            value = size / scale
            return f"{value:.1f} {unit}" if value < 10 else f"{value:.0f} {unit}"
    return f"{size} bytes"


def _read_int(path: str) -> int | None:
    """A file holding one integer (``max``, as cgroups write "no limit", and
    absent files are ``None``)."""
    try:
        with open(path) as file:
            return int(file.read().strip())
    except (OSError, ValueError):
        return None


#: The standard streams: their descriptors, names in ``sys`` and modes.
STANDARD_STREAMS = ((0, "stdin", "r"), (1, "stdout", "w"), (2, "stderr", "w"))
#: The error handler of the command's output streams (see :func:`_escaped`).
ESCAPED = "mitsuba-whitted-escaped"


def open_standard_streams() -> None:
    """/dev/null in place of a standard stream the command was started
    without (``2>&-``), and output streams that write any text, escaped
    where they cannot encode it.

    Python leaves ``sys.stderr`` ``None`` then, where the progress display
    and the error sentence fail; and the next file opened would take the
    free descriptor, so that what a library writes to stderr would go into
    it (an image being written). And a path whose bytes are not UTF-8
    (``$'out\\xff.png'``), which the sentences name, is text that Python's
    stdout refuses to encode."""
    for descriptor, name, mode in STANDARD_STREAMS:
        try:
            os.fstat(descriptor)
        except OSError:
            to_null(descriptor)
        if getattr(sys, name) is None:
            setattr(sys, name, open(descriptor, mode, closefd=False))
    for stream in (sys.stdout, sys.stderr):
        stream.reconfigure(errors=ESCAPED)


def shown(text: str) -> str:
    """``text`` as the command writes it (see :func:`_escaped`)."""
    return text.encode("utf-8", ESCAPED).decode("utf-8")


def _escaped(error: UnicodeEncodeError) -> tuple[str, int]:
    """Text that an encoding cannot take, as escapes: a byte that was not
    UTF-8 in a file name (Python decodes it to a lone surrogate, U+DC80 to
    U+DCFF) as ``\\xff``, as the user writes it in bash's ``$'...'``;
    anything else as Python's ``backslashreplace`` writes it."""
    escaped = "".join(f"\\x{ord(c) - 0xDC00:02x}" if 0xDC80 <= ord(c) <= 0xDCFF
                      else c.encode("ascii", "backslashreplace").decode("ascii")
                      for c in error.object[error.start:error.end])
    return escaped, error.end


codecs.register_error(ESCAPED, _escaped)


def to_null(descriptor: int) -> None:
    """Make ``descriptor`` read from and write to /dev/null."""
    null = os.open(os.devnull, os.O_RDWR)
    if null != descriptor:
        os.dup2(null, descriptor)
        os.close(null)

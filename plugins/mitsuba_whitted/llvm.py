"""Choose a libLLVM that Dr.Jit 1.5 can use, before Dr.Jit loads one.

Dr.Jit 1.5 emits ``llvm.minimum``/``llvm.maximum`` intrinsics. The x86 back
ends of LLVM 14, 15 and 16 cannot select them and abort the whole process
(``LLVM ERROR: Cannot select ... fminimum``), which no ``try`` can catch.
LLVM 19 is known to work. LLVM 17 and 18 are tried once in a child process
(an abort there costs nothing) and the verdict is cached.

The choice is handed to Dr.Jit through ``DRJIT_LIBLLVM_PATH``, which it reads
when its LLVM back end starts, so :func:`configure` must run before the first
LLVM variant is set.
"""

from __future__ import annotations

import glob
import json
import os
import re
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

from .errors import Error
from .files import write_text
from .system import program_command

#: Versions known to abort Dr.Jit 1.5 on x86-64.
BROKEN_BELOW = 17
#: Versions known to work without a probe.
TRUSTED_FROM = 19

SEARCH_PATTERNS = (
    "/usr/lib/x86_64-linux-gnu/libLLVM*.so*",
    "/usr/lib/aarch64-linux-gnu/libLLVM*.so*",
    "/usr/lib/llvm-*/lib/libLLVM*.so*",
    "/usr/lib64/libLLVM*.so*",
    "/usr/lib/libLLVM*.so*",
    "/usr/local/lib/libLLVM*.so*",
    "/usr/local/opt/llvm*/lib/libLLVM*.dylib",
    "/opt/homebrew/opt/llvm*/lib/libLLVM*.dylib",
)

INSTALL_HINT = (
    "install LLVM 19 (Debian/Ubuntu: 'apt-get install libllvm19') or point "
    "DRJIT_LIBLLVM_PATH at a libLLVM of version 17 or newer"
)


class LLVMError(Error, RuntimeError):
    """No libLLVM that Dr.Jit can use is available."""


@dataclass(frozen=True, order=True)
class Candidate:
    version: int
    path: str


def version_of(path: str) -> int | None:
    """Major LLVM version from a library file name (``libLLVM-19.so``,
    ``libLLVM.so.19.1``) or from its ``llvm-N`` directory."""
    name = os.path.basename(path)
    for pattern in (r"libLLVM-(\d+)", r"libLLVM\.so\.(\d+)", r"libLLVM\.(\d+)\.dylib"):
        match = re.search(pattern, name)
        if match:
            return int(match.group(1))
    match = re.search(r"llvm[-@]?(\d+)", path)
    return int(match.group(1)) if match else None


def find_candidates(patterns=SEARCH_PATTERNS) -> list[Candidate]:
    """Every libLLVM on the usual paths, newest version first."""
    found = {}
    for pattern in patterns:
        for path in glob.glob(pattern):
            version = version_of(path)
            if version is not None and os.path.isfile(path):
                real = os.path.realpath(path)
                found.setdefault(real, Candidate(version, path))
    return sorted(found.values(), reverse=True)


def _cache_file() -> Path:
    root = os.environ.get("XDG_CACHE_HOME") or os.path.join(Path.home(), ".cache")
    return Path(root) / "mitsuba-whitted" / "llvm-probe.json"


def probe(path: str) -> bool:
    """Whether Dr.Jit compiles a kernel with ``path``, tried in a child
    process (:mod:`.programs.llvm_probe`) so that an abort cannot take this
    one down. Cached per file."""
    stat = os.stat(path)
    key = f"{os.path.realpath(path)}:{stat.st_size}:{int(stat.st_mtime)}"
    cache = _cache_file()
    try:
        verdicts = json.loads(cache.read_text())
    except (OSError, ValueError):
        verdicts = {}
    if key not in verdicts:
        result = subprocess.run(program_command("llvm_probe", path),
                                capture_output=True, timeout=120)
        verdicts[key] = result.returncode == 0
        try:
            write_text(cache, json.dumps(verdicts))
        except OSError:
            pass
    return bool(verdicts[key])


def usable(candidate: Candidate) -> bool:
    if candidate.version < BROKEN_BELOW:
        return False
    return candidate.version >= TRUSTED_FROM or probe(candidate.path)


def select(candidates: list[Candidate] | None = None) -> Candidate:
    """The newest usable libLLVM, or :class:`LLVMError` saying what to install."""
    candidates = find_candidates() if candidates is None else candidates
    for candidate in candidates:
        if usable(candidate):
            return candidate
    seen = ", ".join(f"{c.path} (LLVM {c.version})" for c in candidates) or "none"
    raise LLVMError(
        f"no libLLVM usable by Dr.Jit was found (found: {seen}; "
        f"LLVM 16 and older abort Dr.Jit 1.5): {INSTALL_HINT}.")


def loaded_library() -> str | None:
    """Path of the libLLVM mapped into this process, if any (Linux only)."""
    try:
        with open("/proc/self/maps") as maps:
            for line in maps:
                if "libLLVM" in line:
                    return line.split()[-1]
    except OSError:
        pass
    return None


def configure() -> str | None:
    """Point Dr.Jit at a usable libLLVM; return its path.

    An explicit ``DRJIT_LIBLLVM_PATH`` is kept when it names a usable
    library and refused with a clear error when it names a known-broken one.
    Without any usable library nothing is set and ``None`` is returned: the
    CUDA variants still work, and :func:`require` explains the problem when an
    LLVM variant is asked for.
    """
    loaded = loaded_library()
    if loaded is not None:
        version = version_of(loaded)
        if version is not None and version < BROKEN_BELOW:
            raise LLVMError(
                f"Dr.Jit has already loaded {loaded} (LLVM {version}), "
                f"which aborts Dr.Jit 1.5: {INSTALL_HINT}, and import "
                "mitsuba_whitted before the first LLVM variant is set.")
        return loaded
    explicit = os.environ.get("DRJIT_LIBLLVM_PATH")
    if explicit:
        version = version_of(explicit)
        if version is not None and version < BROKEN_BELOW:
            raise LLVMError(
                f"DRJIT_LIBLLVM_PATH={explicit} is LLVM {version}, "
                f"which aborts Dr.Jit 1.5: {INSTALL_HINT}.")
        return explicit
    try:
        chosen = select()
    except LLVMError:
        return None
    os.environ["DRJIT_LIBLLVM_PATH"] = chosen.path
    return chosen.path


def require() -> str:
    """Path of the libLLVM in use, or :class:`LLVMError` with what to install."""
    return configure() or select().path


if __name__ == "__main__":  # used by the Makefile: exit 1 when none is usable
    try:
        print(select().path)
    except LLVMError as error:
        print(error, file=sys.stderr)
        sys.exit(1)

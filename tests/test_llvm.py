"""libLLVM selection: LLVM 14, 15 and 16 abort Dr.Jit 1.5 and are never chosen."""

import os
import subprocess
import sys

import pytest

from mitsuba_whitted import llvm

BROKEN = [llvm.Candidate(v, f"/usr/lib/x86_64-linux-gnu/libLLVM-{v}.so") for v in (14, 15, 16)]


@pytest.mark.parametrize("path, version", [
    ("/usr/lib/x86_64-linux-gnu/libLLVM-19.so", 19),
    ("/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1", 19),
    ("/usr/lib/x86_64-linux-gnu/libLLVM-14.0.6.so.1", 14),
    ("/usr/lib/llvm-15/lib/libLLVM.so", 15),
    ("/opt/homebrew/opt/llvm@18/lib/libLLVM.dylib", 18),
    ("/usr/lib/libfoo.so", None),
])
def test_version_from_file_name(path, version):
    assert llvm.version_of(path) == version


def test_broken_versions_are_never_chosen(monkeypatch):
    probed = []
    monkeypatch.setattr(llvm, "probe", lambda path: probed.append(path) or True)
    good = llvm.Candidate(19, "/usr/lib/x86_64-linux-gnu/libLLVM-19.so")
    assert llvm.select(sorted(BROKEN + [good], reverse=True)) == good
    with pytest.raises(llvm.LLVMError, match="apt-get install libllvm19"):
        llvm.select(BROKEN)
    assert probed == []  # known-broken versions are not even tried


def test_untested_versions_are_probed_not_trusted(monkeypatch):
    monkeypatch.setattr(llvm, "probe", lambda path: False)
    with pytest.raises(llvm.LLVMError):
        llvm.select([llvm.Candidate(18, "/x/libLLVM-18.so"), llvm.Candidate(17, "/x/libLLVM-17.so")])


def test_explicit_broken_library_is_refused(monkeypatch):
    monkeypatch.setattr(llvm, "loaded_library", lambda: None)
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", BROKEN[1].path)
    with pytest.raises(llvm.LLVMError, match="LLVM 15, which aborts Dr.Jit"):
        llvm.configure()


def test_this_process_runs_a_usable_library():
    loaded = llvm.loaded_library()
    assert loaded is not None and llvm.version_of(loaded) >= llvm.BROKEN_BELOW


def test_probe_survives_an_aborting_library():
    """The probe runs in a child, so even a library that aborts Dr.Jit
    only yields a 'no' (skipped where no such library is installed)."""
    broken = [c for c in llvm.find_candidates() if c.version < llvm.BROKEN_BELOW]
    if not broken:
        pytest.skip("no LLVM 14-16 installed here")
    env = dict(os.environ, XDG_CACHE_HOME=os.path.join(os.environ.get("TMPDIR", "/tmp"), "probe-test"))
    code = ("from mitsuba_whitted import llvm; import sys; "
            f"sys.exit(0 if llvm.probe({broken[0].path!r}) is False else 1)")
    assert subprocess.run([sys.executable, "-c", code], env=env, timeout=300).returncode == 0


def test_probe_accepts_the_library_in_use(monkeypatch, tmp_path):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert llvm.probe(llvm.loaded_library()) is True


def test_probe_program_imports_dr_jit_and_nothing_of_the_package():
    """The probe's child starts with no libLLVM loaded: importing the
    package (or Mitsuba) would choose and load one first."""
    from mitsuba_whitted.system import program_command
    python, *program = program_command("llvm_probe", llvm.loaded_library())
    result = subprocess.run([python, "-X", "importtime", *program], capture_output=True,
                            text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    imported = {line.split("|")[-1].strip() for line in result.stderr.splitlines()}
    assert "drjit" in imported
    assert not {name for name in imported if name.startswith(("mitsuba", "mitsuba_whitted"))}


# Records DRJIT_LIBLLVM_PATH at the moment Dr.Jit is first imported.
IMPORT_WATCH = """
import os, sys
class Watch:
    def find_spec(self, name, path=None, target=None):
        if name == "drjit" and "seen" not in globals():
            globals()["seen"] = os.environ.get("DRJIT_LIBLLVM_PATH")
        return None
sys.meta_path.insert(0, Watch())
import mitsuba_whitted
print(repr(seen))
print(repr(os.environ.get("DRJIT_LIBLLVM_PATH")))
"""


def test_the_library_is_chosen_before_drjit_is_imported():
    """Dr.Jit maps a libLLVM when it is imported: the package must have
    chosen one by then, or a broken default would load first."""
    env = {k: v for k, v in os.environ.items() if k != "DRJIT_LIBLLVM_PATH"}
    result = subprocess.run([sys.executable, "-c", IMPORT_WATCH], capture_output=True, text=True,
                            env=env, timeout=120)
    assert result.returncode == 0, result.stderr
    at_import, chosen = result.stdout.splitlines()
    assert chosen != "None" and at_import == chosen

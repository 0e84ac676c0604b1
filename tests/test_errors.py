"""Every exception class of the package reaches a person as its own
sentence, without the class's name before it."""

import ast
import errno
import subprocess
import sys
from pathlib import Path

import pytest

from mitsuba_whitted import errors
from mitsuba_whitted.errors import one_sentence

PACKAGE = Path(__file__).resolve().parent.parent / "plugins" / "mitsuba_whitted"


def package_exception_classes() -> list[tuple[str, str]]:
    """(module, class) of every class in the package's sources that derives,
    directly or through another of them, from an exception class."""
    bases, modules = {}, {}
    for path in sorted(PACKAGE.rglob("*.py")):
        module = ".".join(path.relative_to(PACKAGE.parent).with_suffix("").parts)
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ClassDef):
                bases[node.name] = [ast.unparse(b).rsplit(".", 1)[-1] for b in node.bases]
                modules[node.name] = module.removesuffix(".__init__")

    def is_exception(name, seen=()):
        if name in seen:
            return False
        return name.endswith(("Error", "Exception")) and name not in bases or any(
            is_exception(base, seen + (name,)) for base in bases.get(name, ()))

    return sorted((modules[name], name) for name in bases
                  if any(is_exception(base) for base in bases[name]))


CLASSES = package_exception_classes()


def test_the_package_has_its_own_exception_classes():
    """The oracle finds the classes it is meant to (it would pass vacuously
    on an empty list)."""
    names = {name for _, name in CLASSES}
    assert {"ParameterError", "WriteError", "ImageWriteError", "ClusterError",
            "UsageError"} <= names
    assert "EqualError" not in names  # a record of figures, not an exception


@pytest.mark.parametrize("module, name", CLASSES, ids=[name for _, name in CLASSES])
def test_an_error_of_the_package_is_its_own_sentence(module, name):
    """In this process, and in a command run as ``python -m``, where the
    command's own module is ``__main__``."""
    cls = getattr(__import__(module, fromlist=[name]), name)
    error = cls.__new__(cls)
    Exception.__init__(error, "mitsuba-whitted: the file 'a' is missing.")
    assert one_sentence(error) == "mitsuba-whitted: the file 'a' is missing."


def test_a_usage_error_of_a_command_run_as_a_module_is_its_own_sentence(tmp_path):
    result = subprocess.run([sys.executable, "-m", "mitsuba_whitted.cli", "render", "x.xml",
                             "-o", "x.png", "-D", "novalue"], capture_output=True, text=True,
                            cwd=tmp_path, timeout=300)
    assert result.returncode == 2
    assert result.stderr == "mitsuba-whitted: -D expects name=value (got 'novalue').\n"


def test_other_classes_keep_their_name():
    assert one_sentence(KeyError("a")) == "KeyError: 'a'."


@pytest.mark.parametrize("error, detail", [
    (MemoryError("Unable to allocate 8.00 GiB"), "Unable to allocate 8.00 GiB"),
    (OSError(errno.ENOMEM, "Cannot allocate memory"), "[Errno 12] Cannot allocate memory"),
    (RuntimeError("At scene.xml (line 3, col 5): failed to instantiate sensor plugin of type "
                  "\"perspective\": [PluginManager] Error while loading plugin "
                  "\"/x/perspective.so\": /x/perspective.so: failed to map segment from shared "
                  "object."), "perspective.so could not be mapped"),
    (RuntimeError("[parser.cpp:1718] At scene.xml (line 10, col 14): failed to instantiate "
                  "texture plugin of type \"bitmap\": std::bad_alloc"),
     "At scene.xml (line 10, col 14): failed to instantiate texture plugin of type "
     "\"bitmap\": std::bad_alloc"),
], ids=["MemoryError", "ENOMEM", "unmapped-plugin", "bad_alloc-in-plugin"])
def test_memory_that_runs_out_is_one_sentence_naming_the_address_space_limit(monkeypatch, error,
                                                                          detail):
    """Under ``ulimit -v`` the address space, not the machine's memory, is
    what runs out: the sentence says so, and what the limit is."""
    monkeypatch.setattr(errors, "address_space_limit", lambda: 1 << 30)
    assert one_sentence(error) == (f"the process ran out of memory ({detail}) under the "
                                   "address-space limit of 1.0 GiB (ulimit -v 1048576); raise "
                                   "the limit or remove it.")
    monkeypatch.setattr(errors, "address_space_limit", lambda: None)
    assert one_sentence(error) == f"the machine ran out of memory ({detail})."

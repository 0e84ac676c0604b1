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
    assert {"Error", "ParameterError", "WriteError", "ImageFormatError", "ClusterError",
            "UsageError"} <= names


@pytest.mark.parametrize("module, name", CLASSES, ids=[name for _, name in CLASSES])
def test_every_error_of_the_package_derives_from_one_base(module, name):
    cls = getattr(__import__(module, fromlist=[name]), name)
    assert issubclass(cls, errors.Error)
    assert errors.Error.kinds.get(name, errors.Error) is cls


def test_the_base_puts_the_one_prefix_before_the_sentence():
    assert str(errors.UsageError("the file 'a' is missing.")) == \
        "mitsuba-whitted: the file 'a' is missing."
    assert str(errors.VariantError("needs a JIT variant.", "whitted")) == \
        "whitted: needs a JIT variant."
    assert str(errors.ParameterError("phong", "exponent", "must be >= 0 (got -1)")) == \
        "phong: parameter 'exponent' must be >= 0 (got -1)"


def test_the_sources_spell_the_prefix_one_way():
    """The package's name before a message is the command's, with a hyphen."""
    spelled = [path.name for path in PACKAGE.rglob("*.py") if "mitsuba_whitted: " in path.read_text()]
    assert spelled == []


@pytest.mark.parametrize("error", [
    errors.UsageError("the file 'a' is missing."),
    errors.ParameterError("tartan", "frequency", "must be finite (got nan)"),
    errors.VariantError("needs a JIT variant.", "whitted"),
], ids=lambda error: type(error).__name__)
def test_an_error_sent_between_processes_arrives_as_it_was_sent(error):
    """Ray pickles a worker's exception: it must not be made anew from its
    text, which would put the prefix in twice."""
    import pickle

    arrived = pickle.loads(pickle.dumps(error))
    assert type(arrived) is type(error)
    assert str(arrived) == str(error)
    assert vars(arrived) == vars(error)


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

"""One clear sentence for bad input, naming the plugin and the parameter."""

from __future__ import annotations

import errno
import re
from contextlib import contextmanager

from .system import address_space_limit, describe_limit


#: The name the package's own messages begin with (a plugin's begin with
#: the plugin's name).
PACKAGE_NAME = "mitsuba-whitted"


class Error(Exception):
    """The base of the errors this package raises for a person to read: one
    sentence, after the name of what refuses (``source``: the package, or
    one of its plugins), which this puts in front of the ``message``."""

    #: The package's error classes by name: a plugin's error reaches
    #: Mitsuba's loader only as the text of a traceback.
    kinds: dict[str, type] = {}

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        Error.kinds[cls.__name__] = cls

    def __init__(self, message: str, source: str = PACKAGE_NAME):
        self.source = source
        super().__init__(f"{source}: {message}")

    def __reduce__(self):
        # Unpickled (from a Ray worker) as it was, not made from its text again.
        return _remade, (type(self), self.args, self.__dict__)


def _remade(kind: type, args: tuple, state: dict) -> Error:
    error = kind.__new__(kind, *args)
    error.args = args
    error.__dict__.update(state)
    return error


class ParameterError(Error, ValueError):
    """A scene parameter of one of this package's plugins is invalid."""

    def __init__(self, plugin: str, parameter: str, problem: str):
        self.plugin = plugin
        self.parameter = parameter
        super().__init__(f"parameter '{parameter}' {problem}", source=plugin)


def check(condition: bool, plugin: str, parameter: str, problem: str) -> None:
    """Raise :class:`ParameterError` unless ``condition`` holds."""
    if not condition:
        raise ParameterError(plugin, parameter, problem)


def check_choice(value: str, choices, plugin: str, parameter: str) -> str:
    """``value`` if it is one of ``choices``, else a :class:`ParameterError`."""
    check(value in choices, plugin, parameter,
          f"must be one of {', '.join(repr(c) for c in choices)} (got {value!r})")
    return value


class VariantError(Error, RuntimeError):
    """The active Mitsuba variant cannot run this plugin."""


class UsageError(Error):
    """Bad input from the command line, or a scene it cannot use."""


def caused_by(error: BaseException, kind: type) -> bool:
    """Whether an exception of type ``kind`` is ``error`` or in the chain of
    its causes and contexts (Dr.Jit wraps a ``KeyboardInterrupt`` raised
    inside ``dr.freeze`` or ``dr.custom`` into a ``RuntimeError``)."""
    return any(isinstance(link, kind) for link in _chain(error))


def own_error(error: BaseException) -> BaseException | None:
    """The ``KeyboardInterrupt``, or the :class:`Error`, that ``error`` is
    or wraps (as Dr.Jit's custom operations wrap what they raise into a
    ``RuntimeError``); ``None`` if there is none."""
    return next((link for link in _chain(error)
                 if isinstance(link, (KeyboardInterrupt, Error))), None)


@contextmanager
def raising_own(find):
    """Raise, in place of a ``RuntimeError`` of the block, the error of
    this package that ``find`` finds in it (:func:`own_error`,
    :func:`own_loading_error`), unwrapped; other errors pass unchanged."""
    try:
        yield
    except RuntimeError as error:
        own = find(error)
        if own is None:
            raise
        raise own from None


def _chain(error: BaseException):
    seen = set()
    while error is not None and id(error) not in seen:
        seen.add(id(error))
        yield error
        error = error.__cause__ or error.__context__


_TRACEBACK = "Traceback (most recent call last):"
#: A wrapper's message that only points at the exception it wraps.
_POINTS_AT_CAUSE = re.compile(r"\(see above\)\.?$")
#: A C++ source location before a Mitsuba message: "[parser.cpp:451] ".
_SOURCE_LOCATION = re.compile(r"\[[\w.]+\.(?:cpp|h|inl):\d+\] ")
#: Dr.Jit's function names before its message: "drjit...__floordiv__(): jit_var_div(r0, r2): ".
_DRJIT_CALLS = re.compile(r"^(?:(?:drjit\.[\w.]+|jit_\w+)\([^()]*\): )+")
#: Python's exception classes whose name adds nothing to their message.
_GENERIC_CLASSES = {"Exception", "RuntimeError", "ValueError", "OSError"}


def root_cause(error: BaseException) -> BaseException:
    """The exception that says what went wrong: ``error``, unless its
    message is empty or only points at the exception it wraps ("(see
    above)", as Dr.Jit's wrappers say); then that one, in turn."""
    for link in _chain(error):
        text = str(link).strip()
        following = link.__cause__ or link.__context__
        if following is None or (text and not _POINTS_AT_CAUSE.search(text)):
            return link
    return error


def one_sentence(error: BaseException) -> str:
    """One line that says what went wrong, for a person: the real cause
    dug out of the wrappers and the nested messages (a Python traceback
    inside a plugin-loading error, an ``<include>``'s error inside its
    file's, nanobind's list of signatures) that Mitsuba and Dr.Jit make."""
    memory = next((link for link in _chain(error) if _is_out_of_memory(link)), None)
    if memory is not None:
        # Also when it is only the context of the error raised (Dr.Jit's
        # import fails in a NameError after its library could not be mapped).
        return _sentence(_out_of_memory(memory))
    cause = root_cause(error)
    if isinstance(cause, RecursionError):
        return _sentence(f"Python's recursion limit was reached ({cause})")
    name = "" if isinstance(cause, Error) else type(cause).__name__
    text = _plain_line(str(cause), name)
    return _sentence(text or f"{type(cause).__name__} without a message")


#: The dynamic loader's message for a library it could not map into the
#: address space, and the library's file name.
_UNMAPPED = re.compile(r"([^/\s:]+): failed to map segment")
#: C++'s failed allocation in the message of an error that wraps it
#: (Mitsuba's, for a plugin that could not be made).
_BAD_ALLOC = "std::bad_alloc"


def _is_out_of_memory(error: BaseException) -> bool:
    """Whether ``error`` says that memory could not be had: Python's
    ``MemoryError`` (also C++'s ``std::bad_alloc``, which nanobind turns
    into one, or which Mitsuba names in its own error), the system's
    ENOMEM, and the dynamic loader's failure to map a library (an
    ``ImportError``, or Mitsuba's error on loading a plugin)."""
    return (isinstance(error, MemoryError) or getattr(error, "errno", None) == errno.ENOMEM
            or _BAD_ALLOC in str(error) or _UNMAPPED.search(str(error)) is not None)


def _out_of_memory(error: BaseException) -> str:
    """What ran out, said with its cause where the process has an
    address-space limit: that limit, not the machine's memory, is then what
    runs out first."""
    unmapped = _UNMAPPED.search(str(error))
    detail = (f"{unmapped.group(1)} could not be mapped" if unmapped
              else _SOURCE_LOCATION.sub("", str(error)).strip())
    detail = f" ({detail})" if detail else ""
    limit = address_space_limit()
    if limit is None:
        return f"the machine ran out of memory{detail}"
    return f"the process ran out of memory{detail} under {describe_limit(limit)}; " \
           "raise the limit or remove it"


def _plain_line(text: str, name: str) -> str:
    text = _SOURCE_LOCATION.sub("", text)
    lines = [line.rstrip() for line in text.strip().splitlines() if line.strip()]
    if not lines:
        return ""
    # Mitsuba puts a plugin's Python traceback after its heading.
    header = next((i for i, line in enumerate(lines) if _TRACEBACK in line), None)
    if header is not None:
        heading = lines[header].split(_TRACEBACK)[0]
        inner_name, message = _last_exception(lines[header + 1:])
        inner = _plain_line(message, inner_name)
        return inner if _names_its_source(inner_name) else heading + inner
    line = _innermost(lines)
    if _DRJIT_CALLS.match(line):
        line = "Dr.Jit: " + _DRJIT_CALLS.sub("", line)
    if _passes_size_limit(line):
        limit = "" if "2^32" in line else ": more than Dr.Jit's limit of 2^32 entries in one array"
        line = f"{line.rstrip('.!')}{limit}; lower the film's resolution or its samples per pixel"
    return line if _is_plain(name) else f"{name}: {line}"


def _is_plain(name: str) -> bool:
    """Whether a message of the exception class ``name`` (empty for one of
    this package's, whose messages are sentences already) is read without
    the name: Python's generic classes too."""
    return not name or name in _GENERIC_CLASSES or name in Error.kinds


def _names_its_source(name: str) -> bool:
    """Whether an error of the class ``name``, raised in a plugin, says
    which plugin in its own sentence (this package's errors, and the
    ``ValueError`` of its checks), so that Mitsuba's heading adds nothing."""
    return name in Error.kinds or name == "ValueError"


#: Where Mitsuba's scene loader says the plugin it could not make is:
#: 'At dictionary node "i": failed to instantiate', 'At scene.xml (line 3,
#: col 30): failed to instantiate'.
_LOADER_PLACE = re.compile(r"At (.+?): failed to instantiate")
#: The message of a :class:`ParameterError`.
_PARAMETER_MESSAGE = re.compile(r"(\S+): parameter '(.*?)' (.*)", re.DOTALL)


def own_loading_error(error: BaseException) -> BaseException | None:
    """This package's error that a plugin raised while Mitsuba's loader
    made it, raised anew with where the loader says the plugin is; ``None``
    for any other error. The loader keeps only the text of what a Python
    plugin raises: the plugin's traceback, formatted into the message of
    its own ``RuntimeError``."""
    heading, traceback, trace = str(error).rpartition(_TRACEBACK)
    if not traceback:
        return None
    name, message = _last_exception(trace.strip("\n").splitlines())
    kind = Error.kinds.get(name)
    if kind is None:
        return None
    places = _LOADER_PLACE.findall(heading)
    where = f", at {places[-1]}" if places else ""
    parameter = _PARAMETER_MESSAGE.fullmatch(message.strip())
    if issubclass(kind, ParameterError) and parameter:
        return kind(parameter[1], parameter[2], parameter[3].rstrip(".") + where)
    source, _, sentence = message.strip().partition(": ")
    try:
        return kind(sentence.rstrip(".") + where, source)
    except TypeError:  # a class that is not made from its message alone
        return None


def _passes_size_limit(line: str) -> bool:
    """Whether a message is about an array of 2^32 entries or more (Dr.Jit
    names its limit; a tensor's size check shows the size before and after
    it wrapped around 32 bits)."""
    return "2^32" in line or ("size" in line and any(int(n) >= 1 << 32
                                                      for n in re.findall(r"\d{10,}", line)))


def _innermost(lines: list[str]) -> str:
    """The line of a (possibly nested) message that names the cause."""
    first = lines[0].strip()
    # nanobind: "f(): incompatible function arguments. The following ..."
    if "incompatible function arguments" in first:
        invoked = next((line.strip() for line in lines if line.startswith("Invoked with")), "")
        return f"{first.split('. ')[0]} ({invoked[0].lower() + invoked[1:]})" if invoked else first
    # A heading and its list ("Found unused parameters:" and "- $foo=1").
    items = [line.strip()[1:].strip() for line in lines[1:] if line.strip().startswith("-")]
    if first.endswith(":") and items:
        return f"{first} {', '.join(items)}"
    # Mitsuba nests the error of an included file, a plugin or a stream
    # after a heading that ends with a colon: the last line is the cause.
    return lines[-1].strip() if first.endswith(":") else first


def _last_exception(lines: list[str]) -> tuple[str, str]:
    """Class name and message of the last exception of a formatted
    traceback: what follows its last frame ("  File ...") and that
    frame's indented source lines."""
    frames = [i for i, line in enumerate(lines) if line.startswith("  File ")]
    after = frames[-1] + 1 if frames else 0
    start = next((i for i in range(after, len(lines)) if not lines[i].startswith(" ")), after)
    name, _, message = "\n".join(lines[start:]).partition(": ")
    return name.rsplit(".", 1)[-1], message


def _sentence(text: str) -> str:
    text = " ".join(text.split()).rstrip(":")
    return text if text.endswith((".", "!", "?")) else text + "."


class ClusterError(Error, RuntimeError):
    """The cluster cannot run the job, said in one sentence."""

"""One clear sentence for bad input, naming the plugin and the parameter."""

from __future__ import annotations


class ParameterError(ValueError):
    """A scene parameter of one of this package's plugins is invalid."""

    def __init__(self, plugin: str, parameter: str, problem: str):
        self.plugin = plugin
        self.parameter = parameter
        super().__init__(f"{plugin}: parameter '{parameter}' {problem}")


def check(condition: bool, plugin: str, parameter: str, problem: str) -> None:
    """Raise :class:`ParameterError` unless ``condition`` holds."""
    if not condition:
        raise ParameterError(plugin, parameter, problem)


def check_choice(value: str, choices, plugin: str, parameter: str) -> str:
    """``value`` if it is one of ``choices``, else a :class:`ParameterError`."""
    check(value in choices, plugin, parameter,
          f"must be one of {', '.join(repr(c) for c in choices)} (got {value!r})")
    return value


class VariantError(RuntimeError):
    """The active Mitsuba variant cannot run this plugin."""

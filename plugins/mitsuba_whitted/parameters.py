"""Reading, checking and updating the parameters of this package's plugins.

Every value a plugin takes, from a scene file, a dictionary or an update
through ``mi.traverse``, is checked here for its type, its size, NaN/Inf
and its range, with one :class:`~.errors.ParameterError` sentence naming the
plugin and the parameter. :class:`LastValid` makes a refused update change
nothing.
"""

from __future__ import annotations

import operator
from contextlib import contextmanager

import drjit as dr
import mitsuba as mi
import numpy as np

from .errors import ParameterError, check
from .jit import to_int
from .mathutil import invert_affine_f64


#: Float32's resolution (NumPy's ``finfo(float32).resolution``): the
#: smallest length, relative to the position it lies at, that the plugins
#: tell apart there.
FLOAT32_RESOLUTION = 1e-6


def resolution_at(*positions: float) -> float:
    """The smallest length float32 resolves at ``positions``: its
    resolution times their largest magnitude, taken at least 1 (surface
    points carry the rounding of the scene's unit of length, as Mitsuba's
    ray offsets take it)."""
    return FLOAT32_RESOLUTION * max([1.0, *(abs(p) for p in positions)])


def value_text(value) -> str:
    """``value`` as a user wrote it: text quoted, numbers as numbers, other
    objects by their type (their own text may span many lines)."""
    if isinstance(value, str):
        return repr(value)
    numbers = _as_numbers(value)
    if numbers is None:
        return f"a {type(value).__name__}"
    text = ", ".join(f"{x:g}" for x in numbers)
    return text if numbers.size == 1 else f"[{text}]"


def _as_numbers(value) -> np.ndarray | None:
    """The numbers in ``value`` (a number, a sequence, a Mitsuba or Dr.Jit
    array of any width), flat, in float64; ``None`` if it is not numbers."""
    if value is None or isinstance(value, (bool, str, bytes)):
        return None
    try:
        numbers = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        return None
    return numbers.ravel()


def checked_numbers(value, plugin: str, name: str, *, size: int = 1,
                    greater_than: float | None = None, at_least: float | None = None,
                    broadcast: bool = False) -> list[float]:
    """``value`` as a list of ``size`` numbers, or a :class:`ParameterError`
    unless it is exactly that many numbers (one, broadcast to ``size``, if
    ``broadcast``), each finite in float32 (what the plugins store) and
    above the bound given."""
    what = "a finite number" if size == 1 else f"{size} finite numbers"
    if greater_than is not None:
        what += f" > {greater_than:g}"
    if at_least is not None:
        what += f" >= {at_least:g}"
    numbers = _as_numbers(value)
    if numbers is not None and broadcast and numbers.size == 1:
        numbers = np.repeat(numbers, size)
    got = value_text(value)
    check(numbers is not None and numbers.size == size, plugin, name, f"must be {what} (got {got})")
    with np.errstate(over="ignore"):
        in_float32 = np.isfinite(numbers.astype(np.float32))
    if np.isfinite(numbers).all() and not in_float32.all():
        got += ", beyond float32's range"
    valid = in_float32.all()
    if greater_than is not None:
        valid &= bool((numbers > greater_than).all())
    if at_least is not None:
        valid &= bool((numbers >= at_least).all())
    check(valid, plugin, name, f"must be {what} (got {got})")
    return numbers.tolist()


def check_seed(seed, plugin: str, name: str = "seed") -> int:
    """A render seed as a Python number (``mi.render`` passes on what its
    caller gave, a number or an ``mi.UInt32``), or a
    :class:`~.errors.ParameterError` unless 32 bits hold it, as the
    seeds are hashed."""
    try:
        value = operator.index(to_int(seed) if dr.is_array_v(seed) else seed)
    except TypeError:
        value = None
    check(value is not None and 0 <= value < 1 << 32, plugin, name,
          f"must be a whole number from 0 to 2^32 - 1 (got {seed!r})")
    return value


def _matrix(value):
    """The matrix of a Mitsuba transform, else ``None`` (a Dr.Jit vector
    answers ``.matrix`` too, as a swizzle of its components)."""
    return None if dr.is_array_v(value) else getattr(value, "matrix", None)


def checked_transform(value, plugin: str, name: str = "to_world") -> tuple[np.ndarray, np.ndarray]:
    """A placement (any Mitsuba transform, scalar or of width one) as float64
    matrices ``(M, M⁻¹)``, or a :class:`ParameterError` unless it is
    finite, affine and invertible, its inverse finite in float32 too."""
    matrix = _matrix(value)
    check(matrix is not None, plugin, name, f"must be a transform (got {value_text(value)})")
    m = np.asarray(matrix, dtype=np.float64)
    if m.ndim == 3:  # a JIT transform: one matrix per lane
        check(m.shape[2] == 1, plugin, name, f"must be one transform (got {m.shape[2]})")
        m = m[..., 0]
    check(np.isfinite(m).all(), plugin, name, "must be finite (its matrix holds NaN or Inf)")
    check(np.array_equal(m[3], [0.0, 0.0, 0.0, 1.0]), plugin, name,
          f"must be affine (its last row is {value_text(m[3])}, not [0, 0, 0, 1])")
    try:
        inverse = invert_affine_f64(m)
    except np.linalg.LinAlgError:
        raise ParameterError(plugin, name, "must be invertible (its matrix is singular "
                                           "or nearly so)") from None
    with np.errstate(over="ignore"):
        check(np.isfinite(inverse.astype(np.float32)).all(), plugin, name,
              "must be invertible in float32 (its inverse overflows)")
    return m, inverse


def read_texture(props: mi.Properties, name: str, plugin: str, default=None) -> mi.Texture:
    """The texture parameter ``name`` (a nested texture, a colour or a
    number), or a :class:`ParameterError` for anything else, and for a
    colour outside [0, 1], which Mitsuba refuses as a reflectance."""
    try:
        return props.get_texture(name) if default is None else props.get_texture(name, default)
    except RuntimeError:
        value = props.get(name)
        expected = ("a colour with channels from 0 to 1" if isinstance(value, mi.ScalarColor3d)
                    else "a texture, a colour or a number")
        raise ParameterError(plugin, name, f"must be {expected} (got {value_text(value)})") from None


def _is_finite(value) -> bool:
    """Whether a traversed value holds no NaN or Inf (values that are not
    floating point, such as integer buffers or flags, always do)."""
    matrix = _matrix(value)
    if matrix is not None:
        value = matrix
    if isinstance(value, float) or dr.is_array_v(value):
        numbers = np.asarray(value)
        return numbers.dtype.kind != "f" or bool(np.isfinite(numbers).all())
    return True


class LastValid:
    """A plugin's parameters, its nested objects' included, as they were
    after its last accepted load or update; ``parameters_changed`` runs
    inside :meth:`updating` so that a refused update changes nothing.

    ``mi.traverse(...).update()`` writes new values into the very arrays the
    plugins traversed, and only then calls ``parameters_changed``, deepest
    objects first: by the time a plugin sees a bad value, the value is in
    place, and its nested objects (a constant colour, a bitmap) have already
    rebuilt themselves from theirs. So the plugin checks everything before it
    derives any state, and on a refusal writes the last valid values back
    into those same arrays (the user's ``SceneParameters`` keeps working
    with them) and has the nested objects rebuild themselves again.

    Mitsuba's ``update`` keeps its list of objects to notify when one of them
    raises: the next ``update()`` notifies them all again, and finds the old,
    valid values.

    The copies cost no memory of their own: a copied Dr.Jit array shares its
    variable, an update gives the traversed array a new one, and a write in
    place (a scatter) copies a shared variable first. Kept in ``__slots__``
    so that Dr.Jit's traversal of frozen-kernel inputs does not visit them.
    """

    __slots__ = ("_plugin_name", "_nested", "_values")

    def __init__(self, plugin_name: str, nested: bool = True):
        self._plugin_name = plugin_name
        #: Whether nested objects' parameters are the plugin's own (a
        #: texture's nested texture is; a shape's BSDF and emitter are not).
        self._nested = nested
        self._values = None

    @contextmanager
    def updating(self, plugin: mi.Object):
        """Check that every value is finite, run the body (the plugin's
        checks, then what it derives), and keep the values as the last valid
        ones; if anything raises, restore the last valid values before the
        error propagates."""
        try:
            self._check_finite(plugin)
            yield
        except BaseException:
            self._restore(plugin)
            raise
        self._keep(plugin)

    def _parameters(self, plugin: mi.Object) -> mi.SceneParameters:
        params = mi.traverse(plugin)
        if not self._nested:
            params.keep(r"[^.]+$")
        return params

    def _check_finite(self, plugin: mi.Object) -> None:
        params = self._parameters(plugin)
        for key in params.keys():
            check(_is_finite(params[key]), self._plugin_name, key,
                  "must be finite (it holds NaN or Inf)")

    def _keep(self, plugin: mi.Object) -> None:
        params = self._parameters(plugin)
        self._values = {key: _copy(params[key]) for key in params.keys()
                        if not params.flags(key) & mi.ParamFlags.ReadOnly}

    def _restore(self, plugin: mi.Object) -> None:
        if self._values is None:  # refused at load: nothing to restore
            return
        params = self._parameters(plugin)
        for key, value in self._values.items():
            params[key] = value  # in place, and a no-op where unchanged
        # The nested objects whose values came back rebuild what they derive
        # from them, deepest first (as Mitsuba's update does); the plugin
        # itself checks before it derives anything.
        nested = [(depth, node, names) for (depth, node), names
                  in params.nodes_to_update.items() if node is not plugin]
        for _, node, names in sorted(nested, key=lambda item: -item[0]):
            node.parameters_changed(list(names))


def _copy(value):
    """A copy of a traversed value that later writes to it leave alone."""
    if isinstance(value, (bool, int, float, str)):
        return value
    return type(value)(value)

"""The catalog of physical effects that the nominal model leaves out, each switchable with parameters.

An effect has a name, a one-line physical description, the signature it leaves in the data, the equation it
enters, and SI parameters. Four kinds say where it enters:

``pendulum``
    an extra angular acceleration [rad/s^2] added to eq (6): ``function(angle, angular_rate, **params)``.
    Written with numpy operations it works on scalars (simulator) and arrays (diagnosis) alike.
``measurement``
    a change to the measured angle: ``function(angle, **params) -> measured angle`` [rad].
``thrust_gate``
    a factor 0..1 on the thrust given the armature voltage: ``function(armature_voltage, **params)``.
``thrust_lag``
    thrust dynamics: the thrust follows its quasi-static value through a first-order lag (built in).
``measurement_filter``
    the measured angle is read through a low-pass filter (built in, :mod:`aeropend_core.model.sensor_filter`).

Parameters of pendulum-side effects are per unit inertia, as they enter dW/dt.  Parameter names are unique across
the catalog (they are the names every output uses, :mod:`aeropend_core.model.names`).

**One effect, one record.** A built-in effect is declared once, below: name, physics, signature, SI parameters
with bounds and start values, its term in the pendulum equation as *kernel terms* (generic term kinds that the
compiled simulator and the output-error kernel both implement, each parameterised by one of the effect's
parameters: :data:`KERNEL_KINDS`), its weak-form terms if the angle-only weak form can carry it, and the
experiment that separates it from each confusable neighbour.  No other module names a built-in effect.  A user
adds an effect with one small function (the diagnosis compiles it with numba when it is written with math or
numpy functions of scalars, :mod:`aeropend_core.diagnosis.user_kernel`; the simulator runs it in LSODA)::

    from aeropend_core.model.effects import register_effect, EffectParameter

    @register_effect('cubic_spring', 'a hardening spring at the pivot', signature='residual ~ angle^3',
                     parameters=[EffectParameter('stiffness', '1/(s^2 rad^2)', 'cubic spring per inertia', 5.0)])
    def cubic_spring(angle, angular_rate, stiffness):
        return -stiffness * angle ** 3

A pendulum effect whose function also takes a ``thrust`` keyword is given the thrust's angular acceleration
L f / J [rad/s^2] too (simulator and output-error fit), e.g. ``def inflow(angle, angular_rate, loss, thrust)``.
"""
from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field, replace as replaced

import numpy as np

from aeropend_core.errors import AeropendError, UnknownEffectError
from aeropend_core.model.names import DERIVED_PARAMETERS, NOMINAL_PARAMETERS

PENDULUM, MEASUREMENT, THRUST_GATE, THRUST_LAG = 'pendulum', 'measurement', 'thrust_gate', 'thrust_lag'
MEASUREMENT_FILTER = 'measurement_filter'
KINDS = (PENDULUM, MEASUREMENT, THRUST_GATE, THRUST_LAG, MEASUREMENT_FILTER)
EQUATION_OF_KIND = {
    PENDULUM: 'eq (6): dW/dt = ... + term(angle, W)',
    MEASUREMENT: 'measured angle = h(angle)',
    THRUST_GATE: 'eq (6): thrust f -> gate(Va) * f',
    THRUST_LAG: 'eq (6): f -> lagged thrust, time_constant * df/dt = f_eq5 - f',
    MEASUREMENT_FILTER: 'measured angle = low-pass(angle)',
}


@dataclass(frozen=True)
class EffectParameter:
    """One parameter of an effect: name, SI unit, meaning, a typical (physically plausible) value and bounds.

    Parameters
    ----------
    name : str [-]
        Parameter name, unique across the catalog (it names the value in every output).
    unit : str [-]
        Its SI unit as text, e.g. ``'rad/s^2'``.
    description : str [-]
        What it means, one line.
    typical : float [unit]
        A typical, physically plausible value (simulation default; the fit starts from a fraction of it).
    lower, upper : float [unit]
        Bounds of the value (the fit keeps it inside them).
    start : float, optional [unit]
        Where fits start (default: 0.3 x ``typical``, clipped to the bounds).
    scale : float, optional [unit]
        The magnitude of a meaningful change for the optimiser (its variable is scaled by max(|value|, 0.1 scale);
        default 1).

    Examples
    --------
    >>> from aeropend_core import EffectParameter
    >>> stiffness = EffectParameter('cubic_k', '1/s^2', 'cubic spring per inertia', 5.0)
    >>> stiffness.unit, stiffness.typical, stiffness.lower <= stiffness.typical <= stiffness.upper
    ('1/s^2', 5.0, True)
    """

    name: str
    unit: str
    description: str
    typical: float
    lower: float = 0.0
    upper: float = np.inf
    start: float | None = None
    scale: float | None = None

    @property
    def start_value(self) -> float:
        value = 0.3 * self.typical if self.start is None else self.start
        return float(np.clip(value, self.lower, self.upper))


#: Generic term kinds implemented by the compiled kernels (simulator and output error); an effect enters them as
#: ``(kind, parameter name)`` pairs, absent kinds have coefficient 0 (off):
#:
#: ``rate_sign``        dW/dt += -p tanh(W / smoothing)          (p in rad/s^2)
#: ``rate_square``      dW/dt += -p W|W|                          (p in 1/rad)
#: ``angle_linear``     dW/dt += -p y                             (p in 1/s^2)
#: ``measured_offset``  measured angle += p                       (p in rad)
#: ``thrust_lag_time``  p df/dt = f_eq5 - f, f drives dW/dt      (p in s; 0 = no lag)
#: ``thrust_threshold`` f = 0 where Va < p                        (p in V; gate)
#: ``measured_lowpass`` measured angle through the 2nd-order RC ladder with DC delay p (p in s; 0 = none;
#:                      :mod:`aeropend_core.model.sensor_filter`)
KERNEL_KINDS = ('rate_sign', 'rate_square', 'angle_linear', 'measured_offset', 'thrust_lag_time',
                'thrust_threshold', 'measured_lowpass')


@dataclass(frozen=True)
class WeakForm:
    """How an effect enters the angle-only weak form of the pendulum equation (weak SINDy).

    ``terms`` builds the extra library terms (:mod:`aeropend_core.wsindy.library`); ``parameters`` turns the
    fitted coefficients into the effect's parameters: ``parameters(coefficients, delta)`` with ``coefficients``
    the dict of d^2angle/dt^2 coefficients (``'sin(angle)'`` etc.) and ``delta(gradient)`` the delta-method 1-sigma
    of a linear combination ``{term: d value / d coefficient}``; returns ``({name: value}, {name: sigma})`` (0 and
    NaN when the selection dropped the term: no evidence).
    """

    terms: Callable[[], list]
    parameters: Callable[[Mapping[str, float], Callable[[Mapping[str, float]], float]],
                         tuple[dict[str, float], dict[str, float]]]


@dataclass(frozen=True)
class Effect:
    """A physical effect that can be added to the nominal model."""

    name: str
    description: str
    signature: str
    kind: str
    parameters: tuple[EffectParameter, ...]
    function: Callable[..., np.ndarray | float] | None = None
    equation: str = ''
    builtin: bool = field(default=False, compare=False)
    #: ``(kernel kind, parameter name)`` pairs (see :data:`KERNEL_KINDS`); empty for users' function effects.
    kernel_terms: tuple[tuple[str, str], ...] = ()
    #: Extra weak-form terms, if the angle-only weak form can carry this effect.
    weak_form: WeakForm | None = None
    #: Experiment that separates this effect from each confusable neighbour (another effect or a nominal
    #: parameter of :data:`aeropend_core.model.names.NOMINAL_PARAMETERS`).
    separated_from: Mapping[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f'effect {self.name!r}: kind must be one of {KINDS}, got {self.kind!r}')
        if self.kind not in (THRUST_LAG, MEASUREMENT_FILTER) and self.function is None:
            raise ValueError(f'effect {self.name!r} of kind {self.kind!r} needs a function')
        if not self.equation:
            object.__setattr__(self, 'equation', EQUATION_OF_KIND[self.kind])
        for kind, parameter in self.kernel_terms:
            if kind not in KERNEL_KINDS or parameter not in self.parameter_names:
                raise ValueError(f'effect {self.name!r}: kernel term ({kind!r}, {parameter!r}) needs a kind of '
                                 f'{KERNEL_KINDS} and one of its parameters')

    @property
    def parameter_names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.parameters)

    def typical_parameters(self) -> dict[str, float]:
        return {p.name: p.typical for p in self.parameters}

    def start_parameters(self) -> dict[str, float]:
        """Where fits start, SI."""
        return {p.name: p.start_value for p in self.parameters}

    @property
    def compiled(self) -> bool:
        """True when the compiled kernels implement this effect (it has kernel terms covering its kind)."""
        return bool(self.kernel_terms)

    def validate(self, values: Mapping[str, float]) -> dict[str, float]:
        """Check a parameter dict (names, finiteness, bounds) and return it as floats."""
        unknown = set(values) - set(self.parameter_names)
        if unknown:
            raise AeropendError(f'effect {self.name!r} has no parameter {sorted(unknown)}; '
                                f'its parameters are {list(self.parameter_names)}')
        checked = {}
        for parameter in self.parameters:
            if parameter.name not in values:
                raise AeropendError(f'effect {self.name!r} needs a value for {parameter.name!r} '
                                    f'[{parameter.unit}] ({parameter.description})')
            value = float(values[parameter.name])
            if not np.isfinite(value) or not parameter.lower <= value <= parameter.upper:
                raise AeropendError(
                    f'effect {self.name!r}: {parameter.name} = {value!r} {parameter.unit} is outside '
                    f'[{parameter.lower}, {parameter.upper}]')
            checked[parameter.name] = value
        return checked


CATALOG: dict[str, Effect] = {}


def add_effect(effect: Effect, *, replace: bool = False) -> Effect:
    """Put an effect into the catalog (``replace=True`` to overwrite one of the same name)."""
    if effect.name in CATALOG and not replace:
        raise AeropendError(f'an effect named {effect.name!r} is already registered; pick another name')
    for parameter in effect.parameter_names:
        owner = find_parameter(parameter)
        if parameter in NOMINAL_PARAMETERS or (owner and owner[0].name != effect.name):
            raise AeropendError(f'effect {effect.name!r}: parameter name {parameter!r} is already used by '
                                f'{owner[0].name if owner else "the nominal model"}; parameter names must be unique')
    CATALOG[effect.name] = effect
    return effect


@contextmanager
def catalog_scope(*effects: Effect) -> Iterator[dict[str, Effect]]:
    """The catalog for the duration of a ``with`` block: `effects` are registered in it, and on leaving the catalog is
    put back as it was (every effect registered or replaced inside the block is undone).

    An analysis that needs an effect of its own for a while (the discovery stage's ``term_*`` effects, which the fits
    look up by name) registers it inside a scope, so nothing it ran changes what the next analysis in the process
    sees; what it found travels in its result. As python-control's ``config.defaults``, with one test fixture
    (``scoped_catalog`` in tests/conftest.py). Not for threads that register effects at the same time.

    Parameters
    ----------
    *effects : Effect [-]
        Effects registered for the block (replacing one of the same name).

    Yields
    ------
    dict of str -> Effect
        :data:`CATALOG` itself.

    Examples
    --------
    >>> from aeropend_core.model.effects import CATALOG, EffectParameter, catalog_scope, register_effect
    >>> with catalog_scope():
    ...     @register_effect('probe_spring', 'a probe', parameters=[EffectParameter('probe_k', '1/s^2', 'k', 1.0)])
    ...     def probe_spring(angle, angular_rate, probe_k):
    ...         return -probe_k * angle
    ...     'probe_spring' in CATALOG
    True
    >>> 'probe_spring' in CATALOG
    False
    """
    saved = dict(CATALOG)
    try:
        for effect in effects:
            add_effect(effect, replace=True)
        yield CATALOG
    finally:
        CATALOG.clear()
        CATALOG.update(saved)


def register_effect(name: str, description: str, *, parameters: list[EffectParameter], signature: str = '',
                    kind: str = PENDULUM, replace: bool = False, kernel_terms: tuple[tuple[str, str], ...] = (),
                    weak_form: WeakForm | None = None, separated_from: Mapping[str, str] | None = None,
                    equation: str = '') -> Callable[[Callable], Callable]:
    """Decorator registering an effect function in the catalog (see the module docstring).

    The same path declares the built-in effects and a user's own.

    Parameters
    ----------
    name : str [-]
        Name of the effect (``--add NAME``, ``effects={NAME: ...}``); must not be taken unless `replace`.
    description : str [-]
        One-line physical description.
    parameters : list of EffectParameter [-]
        Its parameters, SI units, with typical values and bounds.
    signature : str [-]
        The trace it leaves in the data, e.g. ``'residual ~ angle^3'``.
    kind : {'pendulum', 'measurement', 'thrust_gate'} [-]
        Where the function enters: ``pendulum`` returns an angular acceleration [rad/s^2] added to dW/dt from
        ``(angle [rad], angular_rate [rad/s], **params)``; ``measurement`` returns the measured angle [rad] from
        ``(angle, **params)``; ``thrust_gate`` returns a factor 0..1 on the thrust from
        ``(armature_voltage [V], **params)``.
    replace : bool [-]
        Overwrite an effect of the same name instead of refusing.
    kernel_terms : tuple of (kind, parameter) pairs [-]
        Puts the effect into the compiled kernels (generic kinds of :data:`KERNEL_KINDS`); empty: the Python
        function is used.
    weak_form : WeakForm, optional [-]
        Its terms in weak SINDy, if the weak form can carry it.
    separated_from : mapping of str -> str [-]
        For each confusable effect, the experiment (or hardware value) that separates the two.
    equation : str [-]
        Its term in the pendulum equation as text, for reports.

    Returns
    -------
    callable
        The decorator; it returns the function unchanged.

    Examples
    --------
    >>> from aeropend_core import EffectParameter, catalog_scope, register_effect
    >>> from aeropend_core.model.effects import CATALOG
    >>> with catalog_scope():                                   # registered for this block only
    ...     @register_effect('cubic_spring', 'a hardening spring',
    ...                      parameters=[EffectParameter('cubic_k', '1/s^2', 'cubic spring per inertia', 5.0)])
    ...     def cubic_spring(angle, angular_rate, cubic_k):     # rad, rad/s, 1/s^2 -> rad/s^2
    ...         return -cubic_k * angle ** 3
    ...     'cubic_spring' in CATALOG
    True
    >>> 'cubic_spring' in CATALOG
    False
    """

    def decorator(function: Callable) -> Callable:
        add_effect(Effect(name=name, description=description, signature=signature or 'user-defined', kind=kind,
                          parameters=tuple(parameters), function=function, equation=equation,
                          kernel_terms=tuple(kernel_terms), weak_form=weak_form,
                          separated_from=dict(separated_from or {})), replace=replace)
        return function

    return decorator


def wants_thrust(function: Callable) -> bool:
    """True when a pendulum effect's function takes a ``thrust`` keyword: it is then also given the thrust's angular
    acceleration L f / J [rad/s^2] (a term such as thrust x rate, the propeller's inflow).

    Parameters
    ----------
    function : callable [-]
        The effect's function ``function(angle, angular_rate, **parameters)``.

    Returns
    -------
    bool
        Whether it takes ``thrust``.
    """
    cached = _WANTS_THRUST.get(function)
    if cached is None:
        import inspect
        try:
            cached = 'thrust' in inspect.signature(function).parameters
        except (TypeError, ValueError):
            cached = False
        _WANTS_THRUST[function] = cached
    return cached


_WANTS_THRUST: dict = {}


def get_effect(name: str) -> Effect:
    """The catalog entry for `name`; an unknown name raises :class:`UnknownEffectError` listing the known ones."""
    try:
        return CATALOG[name]
    except KeyError:
        raise UnknownEffectError(
            f'unknown effect {name!r}{did_you_mean(name)}; known effects: {", ".join(sorted(CATALOG))} '
            f'(`aeropend effects` describes them)') from None


def kernel_coefficients(effects: Mapping[str, Mapping[str, float]]) -> dict[str, float]:
    """Coefficient of each kernel kind for resolved effects ``{name: {parameter: value}}`` (absent kinds: 0)."""
    coefficients = dict.fromkeys(KERNEL_KINDS, 0.0)
    for name, values in effects.items():
        for kind, parameter in get_effect(name).kernel_terms:
            coefficients[kind] += float(values[parameter])
    return coefficients


def kernel_parameter(effects: Sequence[str], kind: str) -> str | None:
    """The parameter of one of `effects` that drives kernel `kind` (None if none does)."""
    for name in effects:
        for term_kind, parameter in get_effect(name).kernel_terms:
            if term_kind == kind:
                return parameter
    return None


def separating_experiment(a: str, b: str) -> str | None:
    """The experiment that separates `a` from `b` (effects or nominal parameters), from either's record."""
    for first, second in ((a, b), (b, a)):
        if first in CATALOG and second in CATALOG[first].separated_from:
            return CATALOG[first].separated_from[second]
    return None


#: On a record without a usable armature current (the reduced model, aeropend_core.signals.reduced) an effect found
#: that the data cannot tell from its twin here: a lag on the angle acts as a lag on the thrust in series with the
#: motor's own lag, which the reduced model carries in one profiled time constant and does not fit apart. A random
#: 28.8 Hz log with an 80 ms thrust lag hidden was told "missing effect: angle_filter (50 +- 12 ms)"
#: (bench/foreign_naming.py).
REDUCED_TWINS = {'angle_filter': 'thrust_lag'}

#: Why two effects are hard to tell apart, one physical sentence per pair (said when an experiment designed to
#: separate them is too weak to decide).
WHY_ALIKE = {
    frozenset({'thrust_lag', 'angle_filter'}):
        'a lag of the thrust and a low-pass filter of the measured angle commute in a linear system, so they differ '
        'only through the nonlinearities (sin of the angle, the quadratic thrust, friction), in second order of '
        'the delay: only large, fast swings show the difference',
    frozenset({'angle_offset', 'cable_torque'}):
        'an angle offset and a cable spring both reshape the static thrust-to-angle curve; rests at duty 0 (the '
        'offset is the angle read there) and large angles (the spring is linear, gravity goes as sin) separate '
        'them',
}


def why_alike(a: str, b: str) -> str:
    """Why effects `a` and `b` are hard to tell apart, one sentence ('' when the catalog does not say).

    Parameters
    ----------
    a, b : str [-]
        Effect names.

    Returns
    -------
    str
        The physical reason, without a final full stop.
    """
    return WHY_ALIKE.get(frozenset({a, b}), '')


def find_parameter(parameter: str) -> tuple[Effect, EffectParameter] | None:
    """The catalog effect that has a parameter of this name, and that parameter (None if no effect has it)."""
    for effect in CATALOG.values():
        for candidate in effect.parameters:
            if candidate.name == parameter:
                return effect, candidate
    return None


def parameter_unit(name: str) -> str:
    """SI unit of a nominal, derived or catalog-effect parameter ('' when the name is unknown)."""
    if name in NOMINAL_PARAMETERS:
        return NOMINAL_PARAMETERS[name][0]
    if name in DERIVED_PARAMETERS:
        return DERIVED_PARAMETERS[name][0]
    found = find_parameter(name)
    return found[1].unit if found else ''


def resolve_effects(effects: Mapping[str, Mapping[str, float] | float] | None) -> dict[str, dict[str, float]]:
    """Normalise an effects specification to ``{name: {parameter: value}}`` with validated values.

    A single-parameter effect may be given as ``{name: value}``.
    """
    resolved: dict[str, dict[str, float]] = {}
    for name, values in (effects or {}).items():
        effect = get_effect(name)
        if not isinstance(values, Mapping):
            if len(effect.parameters) != 1:
                raise AeropendError(f'effect {name!r} has parameters {list(effect.parameter_names)}: give them '
                                    f'by name, e.g. {name}.{effect.parameters[0].name}=VALUE')
            values = {effect.parameters[0].name: values}
        resolved[name] = effect.validate(values)
    return resolved


def did_you_mean(name: str) -> str:
    """' (did you mean coulomb_friction?)' for the catalog effect closest to a misspelt `name` ('' when none is
    close).

    Parameters
    ----------
    name : str [-]
        The name as given.

    Returns
    -------
    str
        The hint, with its leading space, or ''.
    """
    import difflib
    close = difflib.get_close_matches(name, list(CATALOG), n=1, cutoff=0.6)
    if not close:           # a prefix or a word of the name ('friction', 'offset')
        close = [known for known in CATALOG if name and (known.startswith(name) or name in known.split('_'))][:1]
    return f' (did you mean {close[0]}?)' if close else ''


def check_effect_names(names: Sequence[str], option: str = 'effects') -> tuple[str, ...]:
    """Effect names given to a model (``--add``, ``--effect``, ``--only``, a node's ``effects``): bare catalog names.

    Parameters
    ----------
    names : sequence of str [-]
        The names as given (blanks and repeats are dropped).
    option : str [-]
        Where they came from, for the messages (e.g. ``'--add'``).

    Returns
    -------
    tuple of str
        The names, stripped, without blanks or repeats, in the order given.

    Raises
    ------
    AeropendError
        ``NAME=VALUE`` for a catalog effect: its parameters are fitted, so only the name is taken.
    UnknownEffectError
        A name not in the catalog (the message lists the known ones).
    """
    result: list[str] = []
    for raw in names:
        name = raw.strip()
        if not name:
            continue
        bare = name.split('=', 1)[0].split('.', 1)[0].strip()
        if '=' in name and bare in CATALOG:
            raise AeropendError(f'{option} {name}: give effect names only, e.g. {option} {bare} (the name only: its '
                                'parameters are estimated from the data)')
        if name not in CATALOG:
            raise UnknownEffectError(f'unknown effect {name!r} in {option}{did_you_mean(name)}; known effects: '
                                     f'{", ".join(sorted(CATALOG))} (`aeropend effects` describes them)')
        if name not in result:
            result.append(name)
    return tuple(result)


def parse_effect_assignments(assignments: list[str]) -> dict[str, dict[str, float]]:
    """Parse CLI ``NAME=VALUE`` or ``NAME.PARAM=VALUE`` strings into a validated effects dict."""
    raw: dict[str, dict[str, float] | float] = {}
    for text in assignments:
        key, sep, value_text = text.partition('=')
        try:
            value = float(value_text)
        except ValueError:
            value = None
        if not sep or value is None:
            raise AeropendError(f'cannot read effect {text!r}: write NAME=VALUE (e.g. coulomb_friction=3.0) or '
                                f'NAME.PARAMETER=VALUE')
        name, _, parameter = key.partition('.')
        if parameter:
            entry = raw.setdefault(name, {})
            if not isinstance(entry, dict):
                raise AeropendError(f'effect {name!r} given twice')
            entry[parameter] = value
        else:
            raw[name] = value
    return resolve_effects(raw)


# ----------------------------------------------------------------------------------------------------------------
# Built-in catalog, one record per effect. Typical values are physically plausible for this rig (docs/model.md
# section 5) and detectable.

#: Width [rad/s] of the smooth sign used for dry friction: tanh(W / width). Below it the pivot is "stuck".
FRICTION_SMOOTHING = 0.01

_LARGE_ANGLES = ('excite larger angles (70-85 deg): the cable\'s linear torque departs from gravity\'s sin(angle) '
                 'only there')


def _weak_cable(coefficients, delta):
    # 0 with no error bar when the selection dropped the term (no evidence of a cable torque)
    if 'angle' not in coefficients:
        return {'cable_stiffness': 0.0}, {'cable_stiffness': float('nan')}
    return {'cable_stiffness': -coefficients['angle']}, {'cable_stiffness': delta({'angle': -1.0})}


def _weak_offset(coefficients, delta):
    # measured y_m = y + d: -a sin(y_m - d) = -a cos d sin y_m + a sin d cos y_m
    a = -coefficients.get('sin(angle)', 0.0)
    wc = coefficients.get('cos(angle)', 0.0)
    ratio = wc / a if a else 0.0
    value = float(np.arcsin(max(-1.0, min(1.0, ratio))))
    error = delta({'cos(angle)': 1 / a, 'sin(angle)': wc / a ** 2}) if a and 'cos(angle)' in coefficients \
        else float('nan')
    return {'angle_offset': value}, {'angle_offset': error}


def _library_term(builder: str, signal: str):
    def terms():
        from aeropend_core.wsindy import library
        return [getattr(library, builder)(signal)]
    return terms


@register_effect(
    'coulomb_friction', 'dry (Coulomb) friction in the pivot bearing, opposing the motion',
    signature='residual ~ sign(W): steps at direction reversals, linear (not exponential) decay of swings',
    parameters=[EffectParameter('friction_acceleration', 'rad/s^2', 'friction torque per unit inertia, Fc', 4.0, 0.0,
                                200.0)],
    equation='eq (6): dW/dt = ... - Fc sign(W)', kernel_terms=(('rate_sign', 'friction_acceleration'),),
    separated_from={
        'gravity_stiffness': 'add free decays (duty 0 after large steps): dry friction stops the swing early, away '
                             'from the bottom',
        'thrust_gain': 'add steps both up and down through the same levels: friction makes the angle depend on the '
                       'direction',
        'damping': 'add free decays of several amplitudes: dry friction decays linearly, viscous damping '
                   'exponentially',
        'quadratic_drag': 'add free decays of several amplitudes: dry friction decays linearly, drag fastest at '
                          'high speed'})
def _coulomb_friction(angle, angular_rate, friction_acceleration):
    return -friction_acceleration * np.tanh(angular_rate / FRICTION_SMOOTHING)


@register_effect(
    'quadratic_drag', 'aerodynamic drag of the rod and motor pod, growing with the square of the speed',
    signature='residual ~ W|W|: damping that grows with swing speed',
    parameters=[EffectParameter('drag_coefficient', '1/rad', 'drag per unit inertia, Cd', 4.0, 0.0, 100.0)],
    equation='eq (6): dW/dt = ... - Cd W|W|', kernel_terms=(('rate_square', 'drag_coefficient'),),
    separated_from={'damping': 'add larger, faster swings (big duty steps): drag grows with the square of the '
                               'speed'})
def _quadratic_drag(angle, angular_rate, drag_coefficient):
    return -drag_coefficient * angular_rate * np.abs(angular_rate)


@register_effect(
    'cable_torque', 'the motor cable acting as a torsion spring about the pivot',
    signature='residual ~ y (linear) next to gravity\'s sin y: differs only at large angles',
    parameters=[EffectParameter('cable_stiffness', '1/s^2', 'cable spring per unit inertia, Kc', 20.0, 0.0,
                                1000.0)],
    equation='eq (6): dW/dt = ... - Kc y', kernel_terms=(('angle_linear', 'cable_stiffness'),),
    weak_form=WeakForm(_library_term('variable', 'angle'), _weak_cable),
    separated_from={'gravity_stiffness': _LARGE_ANGLES,
                    'angle_offset': 'add rests at the bottom (duty 0) and large excursions (70-85 deg)'})
def _cable_torque(angle, angular_rate, cable_stiffness):
    return -cable_stiffness * angle


@register_effect(
    'angle_offset', 'the angle sensor\'s zero is not the hanging position',
    signature='constant offset of the measured angle; looks like a cos(y) term next to sin(y)', kind=MEASUREMENT,
    parameters=[EffectParameter('angle_offset', 'rad', 'measured minus true angle', 0.05, -0.5, 0.5, start=0.0,
                                scale=0.05)],
    equation='measured angle = y + offset', kernel_terms=(('measured_offset', 'angle_offset'),),
    weak_form=WeakForm(_library_term('cosine', 'angle'), _weak_offset),
    separated_from={'gravity_stiffness': 'add rests at duty 0 (rod hanging): the offset is the angle read at rest'})
def _angle_offset(angle, angle_offset):
    return angle + angle_offset


add_effect(Effect(
    'thrust_lag', 'thrust builds up and decays slower than the motor speed (air inflow, propeller inertia)',
    'residual correlates with past input steps: the angle lags the model after each step', THRUST_LAG,
    (EffectParameter('time_constant', 's', 'first-order lag of the thrust', 0.15, 0.0, 5.0, scale=0.1),),
    None, 'tau df/dt = f_eq5 - f, thrust f in eq (6)', kernel_terms=(('thrust_lag_time', 'time_constant'),),
    separated_from={
        'damping': 'add zero-thrust rests longer than the motor spin-down and free-decay segments (they pin the '
                   'damping)',
        'gravity_stiffness': 'add free-decay segments (duty 0 after a large step): they pin the inertia scale '
                             'without thrust'}))


@register_effect(
    'dead_zone', 'no thrust below a threshold armature voltage (stiction of motor and propeller at low duty)',
    signature='model pushes at small duty where the rod does not move', kind=THRUST_GATE,
    parameters=[EffectParameter('threshold_voltage', 'V', 'armature voltage below which the thrust is zero', 0.6,
                                0.0, 3.0)],
    equation='eq (6): f = 0 where Va < threshold', kernel_terms=(('thrust_threshold', 'threshold_voltage'),),
    separated_from={'thrust_gain': 'add steps at small duty (5-20 %): the dead zone shows only there'})
def _dead_zone(armature_voltage, threshold_voltage):
    return (np.asarray(armature_voltage) >= threshold_voltage).astype(float)


add_effect(Effect(
    'angle_filter', 'the angle is read through the sensor\'s 2nd-order RC low-pass (the AS5040\'s PWM output '
    'filtered by R1 = R2 = 4.7 kOhm, C1 = C2 = 1 uF on the rig: delay 3RC = 14.1 ms, cut-off 12.7 Hz)',
    'the measured angle lags the model by a constant delay after every change, also in free decays; like a '
    'thrust lag in the linear regime (lags commute)', MEASUREMENT_FILTER,
    (EffectParameter('filter_delay', 's', 'DC group delay of the angle filter, 3RC for the RC ladder (cut-off '
                     '0.1787/delay Hz; at most 50 ms: a cut-off below 3.6 Hz would blur the pendulum itself)',
                     0.0141, 0.0, 0.05, scale=0.01),),
    None, 'measured angle = H(s) angle, H = 1/((d s/3)^2 + d s + 1)',
    kernel_terms=(('measured_lowpass', 'filter_delay'),),
    separated_from={
        'thrust_lag': 'fix the filter at its hardware value (--fix angle_filter=0.0141 for R1 = R2 = 4.7 kOhm, '
                      'C1 = C2 = 1 uF) or add free decays from large angles (duty 0 after the thrust has died '
                      'away): the filter delays every angle change, the thrust lag only the thrust',
        'damping': 'add free decays of several amplitudes and fast duty steps: the filter delays, damping dissipates',
    }))

# the records above are the built-ins: flagged by new records, not by writing into the frozen ones
CATALOG.update({name: replaced(effect, builtin=True) for name, effect in CATALOG.items()})


def load_effects_module(path: str) -> None:
    """Run a user's Python file that registers effects with :func:`register_effect` (it is executed as code).

    Parameters
    ----------
    path : str [-]
        The file.

    Returns
    -------
    None

    Raises
    ------
    AeropendError
        No such file, or the file failed (its exception named in one line).
    """
    import importlib.util
    from pathlib import Path
    file = Path(path)
    if not file.is_file():
        from aeropend_core.io.paths import path_problem
        raise AeropendError(f'effects module {path} {path_problem(path) or "is not a file"}')
    if file.suffix != '.py':
        # importlib finds no loader for .txt or a bare name, and would load a .so as compiled code: refuse both.
        raise AeropendError(f'effects module {path} is not a Python source file (.py); give the .py file that '
                            'calls register_effect (rename it to end in .py)')
    spec = importlib.util.spec_from_file_location(f'aeropend_user_effects_{file.stem}', file)
    module = importlib.util.module_from_spec(spec)
    try:
        spec.loader.exec_module(module)
    except AeropendError:
        raise
    except SystemExit as error:  # sys.exit() in a user's file must not end aeropend silently (and exit 0)
        raise AeropendError(f'loading {path} failed: it called sys.exit({error.code!r}); an effects module '
                            'only registers effects') from None
    except (Exception, GeneratorExit) as error:  # a user's file: report what went wrong in it, briefly
        raise AeropendError(f'loading {path} failed: {type(error).__name__}: {error}') from None

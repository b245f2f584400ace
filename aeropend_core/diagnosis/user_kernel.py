"""Users' own pendulum effects inside the compiled output-error kernel (numba first-class functions).

A user's effect is a Python function ``function(angle, angular_rate, **parameters[, thrust])``
(:func:`aeropend_core.model.effects.register_effect`). Written with ``math`` or numpy scalar functions (the catalog's
own form), numba compiles it; :func:`compiled_user_terms` then builds one small compiled function

    extra(angle [rad], angular_rate [rad/s], thrust [rad/s^2], row) -> sum of the effects' accelerations [rad/s^2]

that reads each effect's parameters from its columns of the kernel's parameter row, and the kernel
(:func:`aeropend_core.diagnosis.output_error._simulate_kernel`) calls it through a function pointer of the fixed
type :data:`EXTRA_TYPE`: the kernel itself is compiled once (and cached on disk), only the user's function is
compiled in each process (a fraction of a second).

Before it is used, the compiled function is checked against the Python function on a grid of states and parameter
values (to rounding): numba's scalar semantics differ from Python's in corners (integer overflow, a function that
returns an array). A function numba cannot compile, or whose compiled values differ, runs in the numpy path instead,
and the user is told so once per effect (a :class:`UserWarning`, one line on the command line): that path calls
Python at every integration stage and a diagnosis takes minutes.
"""
from __future__ import annotations

import inspect
import itertools
import warnings

import numba
import numpy as np
from numba import types
from numba.core.dispatcher import Dispatcher
from numba.core.errors import NumbaWarning

from aeropend_core.diagnosis.term_kernel import term_value

#: The kernel's type of the users' term: ``extra(angle, angular_rate, thrust, row) -> float``.
EXTRA_SIGNATURE = types.float64(types.float64, types.float64, types.float64, types.float64[::1])
#: The first-class function type the kernel takes it as.
EXTRA_TYPE = types.FunctionType(EXTRA_SIGNATURE)


@numba.njit(EXTRA_SIGNATURE, cache=True, nogil=True)
def no_extra(angle, angular_rate, thrust, row):   # pragma: no cover - compiled; never called (extra_on False)
    """No user term: 0 [rad/s^2] (the kernel's placeholder when every effect is built in)."""
    return 0.0


#: Compiled extra function per tuple of ``(function, {parameter: column})``; None: runs in Python.
_CACHE: dict[tuple, object] = {}
#: Effects whose fall-back to Python has been said (said once per process).
_SAID: set[str] = set()


def compiled_user_terms(terms: list[tuple]) -> object | None:
    """The compiled function that sums the users' pendulum terms, or None when one of them runs only in Python.

    Parameters
    ----------
    terms : list of (callable, dict) [-]
        ``(function, {parameter name: row column})`` per user effect
        (:meth:`aeropend_core.diagnosis.output_error.Structure.user_terms`).

    Returns
    -------
    numba dispatcher or None
        A function of type :data:`EXTRA_TYPE` for the kernel, or None (then a warning has been issued, once per
        effect, naming the effect and why).
    """
    key = tuple((function, tuple(sorted(columns.items()))) for function, columns in terms)
    if key not in _CACHE:
        _CACHE[key] = _compile(terms)
    return _CACHE[key]


def _compile(terms: list[tuple]):
    namespace, calls, single = {'term_value': term_value}, [], None
    for k, (function, columns) in enumerate(terms):
        code = getattr(function, 'term_code', -1)
        if code >= 0:       # a discovered term beside a user's effect: the term kernel's own compiled value
            calls.append(f'row[{int(next(iter(columns.values())))}] * term_value({int(code)}, angle, angular_rate, '
                         'thrust)')
            continue
        try:
            arguments = _arguments(function, columns)
            compiled = function if isinstance(function, Dispatcher) else numba.njit(nogil=True)(function)
            namespace[f'f{k}'] = compiled
            calls.append(f'f{k}({", ".join(arguments)})')
            with warnings.catch_warnings():     # numba's own notes on the user's code are not the user's business
                warnings.simplefilter('ignore', NumbaWarning)
                single = _build({f'f{k}': compiled}, [calls[-1]])
            problem = _disagreement(function, columns, single)
        except Exception as error:    # a user's function: numba's many error types all mean "not compiled"
            problem = f'numba cannot compile it ({_first_line(error)})'
        if problem:
            _say(function, problem)
            return None
    if len(terms) == 1 and single is not None:
        return single
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', NumbaWarning)
        return _build(namespace, calls)


def _arguments(function, columns: dict[str, int]) -> list[str]:
    """The call of `function` inside the extra function, one argument text per parameter of its signature."""
    parameters = list(inspect.signature(function).parameters.values())
    if len(parameters) < 2 or any(p.kind in (p.VAR_POSITIONAL, p.VAR_KEYWORD) for p in parameters):
        raise TypeError('it needs named parameters (angle, angular_rate, its parameters[, thrust]), not *args or '
                        '**kwargs')
    arguments = ['angle', 'angular_rate']
    for parameter in parameters[2:]:
        if parameter.name in columns:
            arguments.append(f'row[{int(columns[parameter.name])}]')
        elif parameter.name == 'thrust':
            arguments.append('thrust')
        elif parameter.default is parameter.empty:
            raise TypeError(f'its argument {parameter.name!r} is neither a parameter of the effect nor thrust')
        else:
            break                       # defaults from here on: keep them
    return arguments


def _build(namespace: dict, calls: list[str]):
    """The compiled ``extra(angle, angular_rate, thrust, row)`` that returns the sum of `calls`."""
    source = 'def extra(angle, angular_rate, thrust, row):\n    return 0.0 + ' + ' + '.join(calls) + '\n'
    exec(compile(source, '<aeropend user effects>', 'exec'), namespace)     # our own generated text
    return numba.njit(EXTRA_SIGNATURE, nogil=True)(namespace['extra'])


#: States (angle [rad], angular rate [rad/s], thrust's angular acceleration [rad/s^2]) the check runs through.
_CHECK_ANGLES = (-1.4, -0.3, 0.0, 0.2, 0.9, 1.5)
_CHECK_RATES = (-6.0, -0.4, -0.004, 0.0, 0.003, 0.5, 7.0)
_CHECK_THRUSTS = (0.0, 0.7, 35.0)


def _disagreement(function, columns: dict[str, int], compiled) -> str | None:
    """None when the compiled function equals the Python one (to rounding) on a grid of states for a few sets of
    parameter values (all typical, all start values, all 0.7 and all -0.3 within their bounds: a coefficient whose
    typical and start values are 0, as a written module's, must not make the check vacuous); else what differs."""
    from aeropend_core.model.effects import find_parameter, wants_thrust
    width = 1 + max(columns.values(), default=0)
    found = [find_parameter(name) for name in columns]
    vectors = []
    for pick in (lambda p: p.typical, lambda p: p.start_value, lambda p: 0.7, lambda p: -0.3):
        vectors.append([float(np.clip(pick(f[1]), f[1].lower, f[1].upper)) if f else 0.7 for f in found])
    thrust = wants_thrust(function)
    for values in vectors:
        row = np.zeros(width)
        for column, value in zip(columns.values(), values):
            row[column] = value
        keywords = dict(zip(columns, values))
        for y, w, t in itertools.product(_CHECK_ANGLES, _CHECK_RATES, _CHECK_THRUSTS if thrust else (0.0,)):
            with np.errstate(all='ignore'):
                expected = float(function(y, w, **keywords, thrust=t) if thrust else function(y, w, **keywords))
                got = compiled(y, w, t, row)
            if not (np.isclose(got, expected, rtol=1e-9, atol=1e-12) or (np.isnan(got) and np.isnan(expected))):
                return (f'compiled, it gives {got!r} where Python gives {expected!r} at angle {y} rad, rate {w} rad/s'
                        f'{f", thrust {t} rad/s^2" if thrust else ""}, parameters {keywords}')
    return None


def _say(function, problem: str) -> None:
    from aeropend_core.model.effects import CATALOG
    name = next((effect.name for effect in CATALOG.values() if effect.function is function),
                getattr(function, '__name__', 'a user effect'))
    if name in _SAID:
        return
    _SAID.add(name)
    warnings.warn(f'effect {name!r} runs in Python, not compiled: its diagnosis will take minutes; {problem}; '
                  'write it with math or numpy functions of scalars to have it compiled', UserWarning, stacklevel=4)


def _first_line(error: Exception) -> str:
    lines = [line.strip() for line in str(error).splitlines() if line.strip()]
    text = next((line for line in lines if not line.startswith(('Failed in', 'No implementation'))),
                lines[0] if lines else type(error).__name__)
    return text[:160]


__all__ = ['EXTRA_SIGNATURE', 'EXTRA_TYPE', 'no_extra', 'compiled_user_terms']

"""Candidate terms for weak SINDy: named functions of named signals, built explicitly.

A :class:`Term` is one column of the library Θ: a name, the signals it reads and a vectorised function of them.
Nothing is applied to a signal unless a term asks for it, so an input such as the armature voltage enters only
the terms listed (no spurious ``sin(armature_voltage)``).

A term may carry a ``derivative_order`` k: its column is then d^k/dt^k of the function, which the weak form
turns into ``(-1)^k ∫ φ^(k) f`` by integrating by parts, so the derivative is never taken from data. That is how
the angular rate enters the live-rig pendulum equation when only the angle is measured.

Examples
--------
>>> from aeropend_core.wsindy import library as lib
>>> terms = lib.polynomial(['armature_current', 'motor_speed'], degree=2) + lib.sine_cosine('angle')
>>> [t.name for t in terms][:3]
['armature_current', 'motor_speed', 'armature_current^2']
"""
from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from itertools import combinations_with_replacement

import numpy as np

Signals = Mapping[str, np.ndarray]


@dataclass(frozen=True)
class Term:
    """One candidate term (one library column).

    Parameters
    ----------
    name : str
        Readable name, e.g. ``'sin(angle)'`` or ``'armature_voltage*armature_current'``.
    variables : tuple of str
        Signals the term reads (checked to exist before a fit).
    function : callable
        ``function(signals) -> ndarray`` of shape ``(n_samples,)``; ``signals`` maps names to arrays of that
        shape. Must be vectorised (no Python loop over samples).
    derivative_order : int
        0 for an ordinary term; k >= 1 for the k-th time derivative of ``function`` (integrated by parts).
    hold : bool
        True when the term's sample k stands for the whole interval [t_k, t_k+1) (a zero-order-hold input such
        as the commanded armature voltage, or an interval average). Its weak integral then uses the midpoint of
        each interval instead of the trapezoid rule; this removes a half-sample time shift that biases damping
        and gain estimates when the input steps.
    partial : callable, optional
        ``partial(signals, name) -> ndarray``: ∂function/∂signal, shape ``(n_samples,)`` (how noise on a signal
        enters the term; the weak-form covariance needs it). Built-in terms give it exactly; without it
        :meth:`derivative_wrt` uses a central difference.
    """

    name: str
    variables: tuple[str, ...]
    function: Callable[[Signals], np.ndarray] = field(repr=False, compare=False)
    derivative_order: int = 0
    hold: bool = False
    partial: Callable[[Signals, str], np.ndarray] | None = field(default=None, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not self.name:
            raise ValueError('a term needs a name')
        if self.derivative_order < 0:
            raise ValueError(f'term {self.name!r}: derivative_order must be >= 0')
        if self.hold and self.derivative_order:
            raise ValueError(f'term {self.name!r}: a held (zero-order-hold) term cannot be a derivative')

    def evaluate(self, signals: Signals) -> np.ndarray:
        """The term's samples, shape ``(n_samples,)`` (before any weak-form derivative)."""
        n = len(next(iter(signals.values())))
        value = np.asarray(self.function(signals), dtype=float)
        return np.broadcast_to(value, (n,)) if value.ndim == 0 else value

    def derivative_wrt(self, signals: Signals, name: str) -> np.ndarray:
        """∂(term)/∂(signal ``name``) at every sample, shape ``(n_samples,)`` (0 if the term does not read it)."""
        n = len(signals[name])
        if name not in self.variables:
            return np.zeros(n)
        if self.partial is not None:
            value = np.asarray(self.partial(signals, name), dtype=float)
            return np.broadcast_to(value, (n,)).copy() if value.ndim == 0 else value
        x = np.asarray(signals[name], float)
        h = 1e-6 * max(float(np.max(np.abs(x))), 1e-12)
        plus, minus = dict(signals), dict(signals)
        plus[name], minus[name] = x + h, x - h
        return (self.evaluate(plus) - self.evaluate(minus)) / (2 * h)


def constant() -> Term:
    """The constant term ``1``."""
    return Term('1', (), lambda s: np.ones(len(next(iter(s.values())))))


def _ones(signals: Signals, name: str) -> np.ndarray:
    return np.ones(len(signals[name]))


def variable(name: str, hold: bool = False) -> Term:
    """The signal itself (``hold=True`` for a zero-order-hold input, see :class:`Term`)."""
    return Term(name, (name,), lambda s, n=name: s[n], hold=hold, partial=_ones)


def product(*names: str, hold: bool = False) -> Term:
    """Product of signals, e.g. ``product('a', 'a')`` is ``a^2``; repeated names are written as powers.

    ``hold=True`` marks a product of zero-order-hold/interval signals (see :class:`Term`).
    """
    if not names:
        return constant()
    counts: dict[str, int] = {}
    for n in names:
        counts[n] = counts.get(n, 0) + 1
    label = '*'.join(n if k == 1 else f'{n}^{k}' for n, k in counts.items())

    def evaluate(s: Signals, names=tuple(names)) -> np.ndarray:
        out = s[names[0]]
        for n in names[1:]:
            out = out * s[n]
        return out

    powers = tuple(counts.items())

    def partial(s: Signals, name: str) -> np.ndarray:
        # d/dx (x^k · rest) = k · x^(k−1) · rest, multiplied in this order: (k·f1)·f2·... (k·1 = k exactly)
        factors = [s[n] for n, k in powers for _ in range(k - 1 if n == name else k)]
        k = dict(powers)[name]
        if not factors:
            return k * np.ones(len(s[name]))
        out = k * factors[0] if k != 1 else np.array(factors[0], dtype=float)
        for factor in factors[1:]:
            out = out * factor
        return out

    return Term(label, tuple(counts), evaluate, hold=hold, partial=partial)


def sine(name: str) -> Term:
    """``sin(name)``."""
    return Term(f'sin({name})', (name,), lambda s, n=name: np.sin(s[n]), partial=lambda s, n: np.cos(s[n]))


def cosine(name: str) -> Term:
    """``cos(name)``."""
    return Term(f'cos({name})', (name,), lambda s, n=name: np.cos(s[n]), partial=lambda s, n: -np.sin(s[n]))


def sine_cosine(name: str) -> list[Term]:
    """``[sin(name), cos(name)]``."""
    return [sine(name), cosine(name)]


def derivative(name: str, order: int = 1) -> Term:
    """The ``order``-th time derivative of a signal, integrated by parts (never differentiated numerically)."""
    label = f'd{name}/dt' if order == 1 else f'd^{order}{name}/dt^{order}'
    return Term(label, (name,), lambda s, n=name: s[n], derivative_order=order, partial=_ones)


def polynomial(names: Sequence[str], degree: int = 2, include_constant: bool = False) -> list[Term]:
    """All monomials of the signals up to ``degree`` (linear terms first, then products and squares)."""
    terms = [constant()] if include_constant else []
    for d in range(1, degree + 1):
        terms += [product(*combo) for combo in combinations_with_replacement(names, d)]
    return terms


def custom(name: str, variables: Sequence[str], function: Callable[[Signals], np.ndarray],
           hold: bool = False) -> Term:
    """A user term: ``function(signals) -> ndarray``, vectorised over samples."""
    return Term(name, tuple(variables), function, hold=hold)


def evaluate(terms: Sequence[Term], signals: Signals) -> np.ndarray:
    """The library matrix Θ, shape ``(n_samples, n_terms)`` (weak-form derivatives not applied)."""
    return np.column_stack([t.evaluate(signals) for t in terms]) if terms else np.empty((0, 0))

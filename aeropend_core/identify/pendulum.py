"""Aeropendulum identification with weak SINDy: the live-rig pendulum fit and the full-state fit of the paper
"Data-Driven System Identification of an Aeropendulum" (``docs/method.md`` section 1.10).

Two problem shapes (paper eqs (1)–(7); :mod:`aeropend_core.wsindy.weak_form` does the regression):

**Live rig** (:func:`identify_pendulum`) — only the armature voltage Va, current Ia and angle y are measured. The
pendulum equation is second order in y, with the thrust of eq (5) written in the measured signals::

    d²y/dt² = −(mgd/J)·sin y − (c/J)·dy/dt + θ1·Va² + θ2·Va·Ia + θ3·Ia²

The weak form integrates by parts twice (∫φ ÿ = ∫φ'' y; the damping term ∫φ ẏ = −∫φ' y), so neither the rate nor
the acceleration is differentiated from data. Derived: mgd/J [1/s²], c/J [1/s], the voltage-thrust acceleration
coefficient k_v = θ1 = (L/J)·Kq / (N1/N2 · Kω)² [rad/s² per V²] (the model's ``thrust_gain``:
ω2 = ω1·N2/N1 as in eq (4); eq (5) prints the gear ratio inverted), and Ra = −θ2/(2θ1) [Ω] (also √(θ3/θ1)).

*Step transients.* Eq (5) assumes Kω·ω1 = Va − Ra·Ia, neglecting La·dIa/dt. With La/Ra ≈ 2 ms ≈ one sample, the
sample right after a duty step sees the new Va but the old Ia, and the quasi-static thrust gets a spurious kick.
Default handling (``step_handling='invert'``): Va is held over each sample interval [t_k, t_k+1) and ω1 barely
changes within it, so the current relaxes exponentially towards (Va − Kω·ω1)/Ra; the interval-equivalent current
``Ĩa_k = (Ia_k+1 − a·Ia_k)/(1 − a)``, a = exp(−Ts·Ra/La), satisfies Va_k − Ra·Ĩa_k = Kω·ω̄1 exactly. Only the
electrical time constant La/Ra is needed (the paper measured it: 2.04 ms); Ra itself stays a fitted quantity. The
thrust terms are then interval quantities and enter the weak form with midpoint (zero-order-hold) quadrature. The
alternative ``'mask'`` drops every test function whose support covers the first ``mask_samples`` samples after a
step; ``'none'`` uses the raw samples (biased).

**Full state** (:func:`identify_full_state`, the paper's case) — X = [Va, Ia, ω1, y, Ω] all available (simulation):
first-order equations dIa/dt, dω1/dt, dy/dt, dΩ/dt over a library of the states' linear terms, products and
squares, sin y, cos y and a constant (17 terms); the input Va enters only linearly (no spurious sin(Va)) and,
by default, only in the armature-circuit equation, where the voltage source acts. Kq follows from the
ω1² coefficient of dΩ/dt, (L/J)·Kq/(N1/N2)², with L/J and the gear known.
"""
from __future__ import annotations

import functools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from itertools import pairwise

import numpy as np

from aeropend_core.wsindy import library as lib
from aeropend_core.model.effects import CATALOG, get_effect
from aeropend_core.model.effects import parameter_unit
from aeropend_core.errors import AeropendError, InsufficientDataError
from aeropend_core.model.parameters import DEFAULT_PARAMETERS, RigParameters
from aeropend_core.io.recording import Recording
from aeropend_core.wsindy.weak_form import (
    Equation,
    WeakSindyResult,
    choose_support,
    fit_weak_sindy,
)
from aeropend_core.signals.preprocess import estimate_noise_std

#: Units of the full-state fit's derived parameters (the pendulum fit's come from the shared vocabulary,
#: :func:`aeropend_core.model.names.parameter_unit`).
PARAMETER_UNITS = {
    'armature_inductance': 'H', 'back_emf_constant': 'V s/rad', 'motor_inertia_per_torque_constant': 'kg m^2/(N m/A)',
    'lever_per_inertia_times_thrust_coefficient': '1/(kg m) N s^2',
}


def parameter_unit_of(name: str) -> str:
    """SI unit of a parameter this module reports."""
    return PARAMETER_UNITS.get(name) or parameter_unit(name)


#: Units of each signal, for printing equations.
SIGNAL_UNITS = {'angle': 'rad', 'armature_voltage': 'V', 'armature_current': 'A', 'motor_speed': 'rad/s',
                'angular_rate': 'rad/s'}



def weak_form_effects() -> list[str]:
    """Catalog effects that the angle-only weak form can carry as extra library terms (their records say how)."""
    return [name for name, effect in CATALOG.items() if effect.weak_form is not None]

_SIN, _RATE, _VV, _VI, _II = ('sin(angle)', 'dangle/dt', 'armature_voltage^2',
                             'armature_voltage*armature_current', 'armature_current^2')


@dataclass(frozen=True, eq=False)
class PendulumFit:
    """Result of :func:`identify_pendulum`.

    Attributes
    ----------
    parameters : dict
        Derived physical parameters, SI (see :data:`PARAMETER_UNITS`): ``gravity_stiffness`` mgd/J [1/s²],
        ``damping`` c/J [1/s], ``thrust_gain`` k_v [rad/s²/V²], ``armature_resistance`` Ra [Ω],
        ``armature_resistance_from_current_square`` √(θ3/θ1) [Ω], ``thrust_coefficient`` Kq [N s²] (from k_v with
        the known gear, Kω and L/J), plus the parameters of the effects asked for (names as in the catalog and
        in the output-error fit: one vocabulary, :mod:`aeropend_core.model.names`).
    estimator : str
        ``'weak_sindy'``.
    standard_errors : dict
        1σ of each parameter (delta method on the coefficient covariance).
    result : WeakSindyResult
        The regression itself (coefficients of d²angle/dt², their standard errors, support, residual).
    step_handling : str
        How duty-step transients were handled.
    """

    parameters: dict[str, float]
    standard_errors: dict[str, float]
    result: WeakSindyResult = field(repr=False)
    step_handling: str = 'invert'
    estimator: str = 'weak_sindy'

    @property
    def equation(self):
        return self.result.equations[0]

    def format(self) -> str:
        lines = [f'{self.equation.name} [rad/s^2] = '
                 + _format_terms(self.equation.coefficients, self.equation.standard_errors, self.equation.name)]
        effect_parameters = {p for name in weak_form_effects() for p in get_effect(name).parameter_names}
        for k, v in self.parameters.items():
            se = self.standard_errors.get(k, float('nan'))
            if k in effect_parameters and not math.isfinite(se):
                lines.append(f'  {k} = 0 {parameter_unit_of(k)} (term not selected: no evidence of the effect)')
            else:
                lines.append(f'  {k} = {v:.6g} ± {se:.2g} {parameter_unit_of(k)}')
        return '\n'.join(lines)


@dataclass(frozen=True, eq=False)
class FullStateFit:
    """Result of :func:`identify_full_state`: ``parameters``/``standard_errors`` (SI) and the regression."""

    parameters: dict[str, float]
    standard_errors: dict[str, float]
    result: WeakSindyResult = field(repr=False)

    def format(self) -> str:
        lines = [f'{eq.name} [{_lhs_unit(eq.name)}] = ' + _format_terms(eq.coefficients, eq.standard_errors, eq.name)
                 for eq in self.result.equations]
        lines += [f'  {k} = {v:.6g} ± {self.standard_errors.get(k, float("nan")):.2g} {parameter_unit_of(k)}'
                  for k, v in self.parameters.items()]
        return '\n'.join(lines)


def _term_unit(term: str) -> str:
    """SI unit of a library term's value, from its name (products, powers, sin/cos, d/dt)."""
    if term == '1' or term.startswith(('sin(', 'cos(')):
        return '1'
    if term.startswith('d') and term.endswith('/dt'):
        return f'{SIGNAL_UNITS.get(term[1:-3], "?")}/s'
    parts = []
    for factor in term.split('*'):
        name, _, power = factor.partition('^')
        unit = SIGNAL_UNITS.get(name, '?')
        if power and '/' in unit:
            unit = f'({unit})'
        parts.append(f'{unit}^{power}' if power else unit)
    return '·'.join(parts)


def _lhs_unit(name: str) -> str:
    for order, suffix in ((2, '/dt^2'), (1, '/dt')):
        if name.endswith(suffix):
            target = name[3 if order == 2 else 1:-len(suffix)]
            unit = SIGNAL_UNITS.get(target, '?')
            if unit.endswith('/s'):
                return unit + ('^3' if order == 2 else '^2')
            return unit + ('/s^2' if order == 2 else '/s')
    return '?'


def _format_terms(coefficients: Mapping[str, float], errors: Mapping[str, float], lhs: str = '') -> str:
    """``(c ± σ)·term [coefficient unit] + ...``."""
    if not coefficients:
        return '0'
    lhs_unit = _lhs_unit(lhs) if lhs else ''
    out = []
    for k, c in coefficients.items():
        unit = ''
        if lhs_unit:
            term_unit = _term_unit(k)
            unit = f' [{lhs_unit}]' if term_unit == '1' else f' [({lhs_unit})/({term_unit})]'
        out.append(f'({c:+.6g} ± {errors.get(k, float("nan")):.2g}{unit})·{k}')
    return '\n    + '.join(out)


# ------------------------------------------------------------------------------------------------ helpers
def _segments(*arrays):
    """Normalise (time, signals...) given either as arrays or as equal-length sequences of arrays."""
    first = arrays[0]
    if isinstance(first, np.ndarray) and first.ndim == 1 or (
            isinstance(first, Sequence) and len(first) and np.isscalar(first[0])):
        return [tuple(np.asarray(a, float) for a in arrays)]
    lists = [list(a) for a in arrays]
    if len({len(x) for x in lists}) != 1:
        raise AeropendError('give the same number of segments for time, voltage, current and angle')
    return [tuple(np.asarray(a[i], float) for a in lists) for i in range(len(lists[0]))]


def _check_finite(names, arrays, label):
    """Refuse NaN/inf/absurd values and shape mismatches (the data-quality gate's rule for plain arrays)."""
    from aeropend_core.signals.quality import require_finite
    require_finite(names, arrays, label)


def step_indices(armature_voltage: np.ndarray, threshold: float | None = None) -> np.ndarray:
    """Indices k where Va[k] differs from Va[k−1] by more than ``threshold`` [V] (default: 6 σ of the sample-to-
    sample noise, at least 10 mV)."""
    v = np.asarray(armature_voltage, float)
    jump = np.abs(np.diff(v))
    if threshold is None:
        d = np.diff(v)
        noise = 1.4826 * float(np.median(np.abs(d - np.median(d))))
        threshold = max(6.0 * noise, 0.01)
    return np.flatnonzero(jump > threshold) + 1


def interval_current(armature_current: np.ndarray, sample_time: float, electrical_time_constant: float):
    """Ĩa_k = (Ia_k+1 − a·Ia_k)/(1 − a), a = exp(−Ts/τe): the current for which Va_k − Ra·Ĩa_k = Kω·ω̄1 over
    [t_k, t_k+1) under a held Va (shape (n − 1,), A). See the module docstring."""
    a = math.exp(-sample_time / electrical_time_constant)
    i = np.asarray(armature_current, float)
    return (i[1:] - a * i[:-1]) / (1.0 - a)


def hold_average(armature_voltage: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """Va replaced by its mean over each run between steps (a held input is constant there), shape (n,) [V]."""
    v = np.asarray(armature_voltage, float)
    edges = np.concatenate([[0], steps, [v.size]])
    out = np.empty_like(v)
    for a, b in pairwise(edges):
        if b > a:
            out[a:b] = v[a:b].mean()
    return out


def denoise_inputs(armature_voltage: np.ndarray, armature_current: np.ndarray, sample_time: float,
                   resistance: float, cutoff: float = 25.0,
                   steps: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Denoise Va and the (interval) current without smearing the duty steps.

    Va is held, so it is averaged over each run between ``steps`` (indices where the duty changes; no averaging
    when None — steps detected from a noisy Va alone are not reliable enough). The back-EMF voltage
    u = Va − R0·Ia (= Kω·ω1, continuous through steps because of the rotor's inertia) is low-passed with a
    zero-phase 2nd-order Butterworth at ``cutoff`` [Hz] and Ia rebuilt as (Va − u)/R0. This is a linear change of
    variables, so the thrust terms stay exact for any R0 near Ra (R0 only has to make u smooth); Ra is still
    fitted. Noise in the quadratic thrust terms otherwise biases every coefficient by errors in variables (~4 % at
    50 dB).
    """
    from scipy.signal import butter, sosfiltfilt
    va = np.asarray(armature_voltage, float) if steps is None else hold_average(armature_voltage, steps)
    u = va - resistance * np.asarray(armature_current, float)
    nyquist = 0.5 / sample_time
    if cutoff < nyquist and u.size > 30:
        sos = butter(2, cutoff / nyquist, output='sos')
        u = sosfiltfilt(sos, u)
    return va, (va - u) / resistance


def _delta(grad: Mapping[str, float], cov: np.ndarray, names: Sequence[str]) -> float:
    g = np.array([grad.get(n, 0.0) for n in names])
    return float(math.sqrt(max(g @ cov @ g, 0.0)))


# ------------------------------------------------------------------------------------------- live-rig fit
def identify_pendulum(time, armature_voltage, armature_current, angle, *,
                      effects: Sequence[str] = (),
                      step_handling: str = 'invert',
                      parameters: RigParameters = DEFAULT_PARAMETERS,
                      electrical_time_constant: float | None = None,
                      mask_samples: int = 4,
                      half_width: int | None = None,
                      min_voltage_range: float = 0.05,
                      denoise: bool = True,
                      input_cutoff: float = 25.0,
                      duty=None,
                      **wsindy_options) -> PendulumFit:
    """Identify the pendulum equation from the rig's measured signals only (fast; safe to call on windows).

    Parameters
    ----------
    time : ndarray, shape (n,) [s]
        Uniformly sampled times, or a sequence of such arrays (segments fitted together).
    armature_voltage : ndarray, shape (n,) [V]
        Va (or a sequence, one per segment), held over each sample interval (from the duty by eq (8)).
    armature_current : ndarray, shape (n,) [A]
        Ia (or a sequence), sampled at t_k.
    angle : ndarray, shape (n,) [rad]
        Rod angle (or a sequence).
    effects : sequence of str [-]
        Catalog effects to add as candidate terms (thresholded by MSTLS; the nominal terms are always kept): those
        whose record has a weak form (:func:`weak_form_effects`: a cable spring as the term angle, a sensor offset
        as cos(angle)). Effects needing the angular rate inside a nonlinearity (friction, drag) or the thrust
        history (lag, dead zone) cannot be written in this weak form: use the output-error diagnosis.
    step_handling : {'invert', 'mask', 'none'} [-]
        Duty-step transient handling (module docstring).
    parameters : RigParameters [SI, see RigParameters]
        Known values used for derived quantities: gear ratio, Kω, L/J (for Kq) and La/Ra (for 'invert').
    electrical_time_constant : float, optional [s]
        La/Ra for 'invert'; default ``parameters.electrical_time_constant``.
    mask_samples : int [samples]
        Samples after each step excluded with 'mask'.
    half_width : int, optional [samples]
        Test-function half-width; default from the angle's spectrum.
    min_voltage_range : float [V]
        Required peak-to-peak armature voltage; less means no excitation and raises.
    denoise : bool [-]
        Denoise Va and Ia before forming the thrust terms (:func:`denoise_inputs`, with R0 =
        ``parameters.armature_resistance``).
    input_cutoff : float [Hz]
        Cut-off of the zero-phase low-pass in :func:`denoise_inputs`.
    duty : ndarray, shape (n,), optional, dimensionless
        The commanded duty fraction (or a sequence). Where it is constant, Va is held, so Va is averaged there
        (removes Va noise, ~1-2 % of bias at 50 dB otherwise). Give it whenever it is recorded.
    **wsindy_options : [as fit_weak_sindy]
        Passed to :func:`aeropend_core.wsindy.weak_form.fit_weak_sindy` (e.g. ``threshold``, ``ridge``).

    Returns
    -------
    PendulumFit
        Derived parameters in SI with 1σ standard errors (``parameters``, ``standard_errors``) and the regression.

    Raises
    ------
    InsufficientDataError
        NaN/inf, a window shorter than the test-function support, or no excitation (constant voltage).
    UnknownEffectError, AeropendError
        Unknown effect name, an effect this fit cannot express, bad options.
    """
    if step_handling not in ('invert', 'mask', 'none'):
        raise AeropendError(f"step_handling must be 'invert', 'mask' or 'none', got {step_handling!r}")
    extra = []
    for name in effects:
        weak = get_effect(name).weak_form        # unknown name -> UnknownEffectError listing the catalog
        if weak is None:
            raise AeropendError(f'effect {name!r} cannot be written as a term of the angle-only weak form; '
                                f'identify_pendulum supports {sorted(weak_form_effects())} (use the diagnosis for '
                                f'others)')
        extra.extend((name, term) for term in weak.terms())
    segments = _segments(time, armature_voltage, armature_current, angle)
    duties = [None] * len(segments) if duty is None else [d for (d,) in _segments(duty)]
    if len(duties) != len(segments):
        raise AeropendError('give one duty array per segment')
    tau = float(electrical_time_constant or parameters.electrical_time_constant)
    times, signals, excludes = [], [], []
    v_range = 0.0
    input_noise = {'armature_voltage': 0.0, 'armature_current': 0.0}
    for i, ((t, va, ia, y), du) in enumerate(zip(segments, duties)):
        label = f'segment {i}: ' if len(segments) > 1 else ''
        _check_finite(('time', 'armature_voltage', 'armature_current', 'angle'), (t, va, ia, y), label)
        if t.size < 8:
            raise InsufficientDataError(f'{label}only {t.size} samples; identify_pendulum needs a window of data')
        v_range = max(v_range, float(np.ptp(va)))
        exclude = None
        dt = float(np.median(np.diff(t)))
        # White-equivalent noise of the inputs as they enter the thrust terms: the weak integrals only see low
        # frequencies, where both the interval inversion ((Ia_k+1 − a·Ia_k)/(1 − a), gain 1 at DC) and the
        # zero-phase low-pass of denoise_inputs pass the raw noise unchanged: use the raw level.
        input_noise['armature_current'] = max(input_noise['armature_current'], estimate_noise_std(ia))
        if du is None or not denoise:
            input_noise['armature_voltage'] = max(input_noise['armature_voltage'], estimate_noise_std(va))
        handling = step_handling
        if handling == 'invert' and dt > INVERT_MAX_STEP * tau:
            # a sample many La/Ra long: the motor speed moves within it, and the inversion (which needs w1 constant
            # over the sample) would shift Ia by a sample; the raw samples are less wrong (bench/rate_sweep.py)
            handling = 'none'
        if handling == 'invert':
            ia_eff = interval_current(ia, dt, tau)
            t, va, y = t[:-1], va[:-1], y[:-1]
            if denoise:
                steps = None if du is None else np.flatnonzero(np.diff(np.asarray(du, float)[:-1])) + 1
                va, ia_eff = denoise_inputs(va, ia_eff, dt, parameters.armature_resistance, input_cutoff, steps)
        else:
            ia_eff = ia
            if handling == 'mask':
                exclude = np.zeros(t.size, bool)
                for k in step_indices(va):
                    exclude[k:k + mask_samples] = True
        times.append(t)
        signals.append({'angle': y, 'armature_voltage': va, 'armature_current': ia_eff})
        excludes.append(exclude)
    # Too short for the test functions? Say so before judging the excitation (a short window rarely has any).
    longest = max(len(t) for t in times)
    support = 2 * (half_width or choose_support(max(signals, key=lambda sig: len(sig['angle']))['angle'], 2)[0]) + 1
    if longest < support:
        raise InsufficientDataError(
            f'window of {longest} samples ({longest * dt:.3g} s) is shorter than the test-function support for '
            f'd^2angle/dt^2: 2m+1 = {support} samples ({support * dt:.3g} s); record longer windows')
    if v_range < min_voltage_range:
        raise InsufficientDataError(
            f'no excitation: the armature voltage varies by only {v_range:.3g} V (< {min_voltage_range:g} V) in the '
            'window, so thrust cannot be told from gravity; apply duty steps (e.g. the Latin-hypercube excitation)')
    terms = [lib.sine('angle'), lib.derivative('angle'),
             lib.product('armature_voltage', 'armature_voltage', hold=True),
             lib.product('armature_voltage', 'armature_current', hold=True),
             lib.product('armature_current', 'armature_current', hold=True)]
    nominal = tuple(t.name for t in terms)
    terms += [term for _, term in extra]
    # Noise levels of the inputs estimated on the raw signals (the denoised ones would fool the estimator);
    # Va averaged over held runs (duty given) counts as noiseless.
    options = {'threshold': 'auto' if extra else None, 'noise_std': input_noise}
    options.update(wsindy_options)
    equation = Equation('angle', tuple(terms), order=2, keep=nominal)
    result = fit_weak_sindy(times if len(times) > 1 else times[0], signals if len(signals) > 1 else signals[0],
                            [equation], half_width=half_width,
                            exclude=excludes if any(e is not None for e in excludes) else None, **options)
    return _pendulum_parameters(result, parameters, [name for name, _ in extra], handling)


#: Longest sample [in units of La/Ra] for which the 'invert' step handling is used; longer samples (below ~160 Hz
#: with La/Ra = 2 ms) use the raw samples ('none').
INVERT_MAX_STEP = 3.0


def _pendulum_parameters(result: WeakSindyResult, parameters: RigParameters, effects, step_handling) -> PendulumFit:
    eq = result.equations[0]
    c = eq.coefficients
    names = list(c)
    cov = eq.covariance
    th1, th2, th3 = c.get(_VV, 0.0), c.get(_VI, 0.0), c.get(_II, 0.0)
    a = -c.get(_SIN, 0.0)
    values, errors = {}, {}
    values['gravity_stiffness'] = a
    errors['gravity_stiffness'] = _delta({_SIN: -1.0}, cov, names)
    values['damping'] = -c.get(_RATE, 0.0)
    errors['damping'] = _delta({_RATE: -1.0}, cov, names)
    values['thrust_gain'] = th1
    errors['thrust_gain'] = _delta({_VV: 1.0}, cov, names)
    if th1 != 0.0:
        values['armature_resistance'] = -th2 / (2 * th1)
        errors['armature_resistance'] = _delta({_VI: -1 / (2 * th1), _VV: th2 / (2 * th1 ** 2)}, cov, names)
        ratio = th3 / th1
        values['armature_resistance_from_current_square'] = math.sqrt(ratio) if ratio > 0 else float('nan')
        if ratio > 0:
            r = math.sqrt(ratio)
            errors['armature_resistance_from_current_square'] = _delta(
                {_II: 0.5 / (r * th1), _VV: -0.5 * th3 / (r * th1 ** 2)}, cov, names)
    scale = (parameters.gear_ratio * parameters.back_emf_constant) ** 2 / parameters.lever_per_inertia
    values['thrust_coefficient'] = th1 * scale
    errors['thrust_coefficient'] = errors['thrust_gain'] * scale
    for name in dict.fromkeys(effects):
        effect_values, effect_errors = get_effect(name).weak_form.parameters(
            c, lambda gradient: _delta(gradient, cov, names))
        values.update(effect_values)
        errors.update(effect_errors)
    return PendulumFit(values, errors, result, step_handling)


# ------------------------------------------------------------------------------------------ full-state fit
#: Equations of the full-state case, in order.
FULL_STATE_TARGETS = ('armature_current', 'motor_speed', 'angle', 'angular_rate')
#: Where the input Va is offered by default: the armature circuit, the only place the voltage source acts.
VOLTAGE_INPUT_EQUATIONS = ('armature_current',)


#: Family-wise level of the significance guard on the selected full-state terms (see ``fit_weak_sindy``).
FULL_STATE_SIGNIFICANCE = 0.05


def full_state_library(include_constant: bool = True, with_voltage: bool = True) -> list[lib.Term]:
    """Paper's library: linear terms, products and squares of the states (Ia, ω1, y, Ω), sin y, cos y, a constant,
    and (``with_voltage``) the input Va linearly only (held over each sample interval): 18 terms."""
    states = ['armature_current', 'motor_speed', 'angle', 'angular_rate']
    terms = lib.polynomial(states, degree=2, include_constant=include_constant) + lib.sine_cosine('angle')
    return terms + [lib.variable('armature_voltage', hold=True)] if with_voltage else terms


@functools.lru_cache(maxsize=8)
def _default_full_state_equations(voltage_in: tuple[str, ...]) -> list[Equation]:
    """The four default equations (terms are immutable, so they are built once per voltage_in)."""
    return [Equation(n, tuple(full_state_library(with_voltage=n in voltage_in))) for n in FULL_STATE_TARGETS]


def identify_full_state(recording: Recording | Mapping[str, np.ndarray] | Sequence, *,
                        parameters: RigParameters = DEFAULT_PARAMETERS,
                        terms: Sequence[lib.Term] | None = None,
                        voltage_in: Sequence[str] = VOLTAGE_INPUT_EQUATIONS,
                        **wsindy_options) -> FullStateFit:
    """Identify the paper's four first-order equations from X = [Va, Ia, ω1, y, Ω] (simulation data).

    Parameters
    ----------
    recording : Recording, mapping or sequence of them
        Needs ``t`` (mapping) / ``time``, ``armature_voltage`` [V], ``armature_current`` [A], ``motor_speed``
        [rad/s], ``angle`` [rad], ``angular_rate`` [rad/s] (``true_*`` columns are used when the plain ones are
        absent). A sequence is fitted as several segments.
    parameters : RigParameters
        Known gear ratio and L/J for Kq.
    terms : sequence of Term, optional
        Candidate library for every equation. Default: :func:`full_state_library` (17 state terms) in every
        equation, plus the input Va in the equations named by ``voltage_in`` only.
    voltage_in : sequence of str
        Equations (targets) whose library includes Va; default the armature circuit only. Offering Va to
        dω1/dt as well makes the support ambiguous at 490 Hz: with La/Ra ≈ one sample the current is slaved,
        Va ≈ Ra·Ia + Kω·ω1, so {Ia, Va} fits as well as {Ia, ω1} (about a quarter of 40 dB records then swap
        the small friction term for Va).
    **wsindy_options
        Passed to :func:`aeropend_core.wsindy.weak_form.fit_weak_sindy` (defaults: threshold 'auto', significance
        :data:`FULL_STATE_SIGNIFICANCE`: a selected term must be significant at the 5 % family-wise level over
        the candidates, which removes the occasional noise look-alike in dIa/dt at 40 dB).

    Returns
    -------
    FullStateFit
        ``parameters``: ``thrust_coefficient`` Kq [N s²], ``lever_per_inertia_times_thrust_coefficient``,
        ``gravity_stiffness``, ``damping``, ``armature_resistance``, ``armature_inductance``,
        ``back_emf_constant`` (from dIa/dt), each with a standard error.
    """
    recs = list(recording) if isinstance(recording, Sequence) and not isinstance(recording, Mapping) \
        else [recording]
    names = ('armature_voltage', 'armature_current', 'motor_speed', 'angle', 'angular_rate')
    times, signals = [], []
    for rec in recs:
        if isinstance(rec, Recording):
            t = rec.time
            sig = {n: rec.signal(n) for n in names}
        else:
            if 't' not in rec and 'time' not in rec:
                raise AeropendError('full-state data needs a time column t')
            t = np.asarray(rec['t'] if 't' in rec else rec['time'], float)
            sig = {}
            for n in names:
                key = n if n in rec else f'true_{n}'
                if key not in rec:
                    raise AeropendError(f'full-state identification needs {n!r} (or true_{n}); '
                                        'only simulations provide motor_speed and angular_rate')
                sig[n] = np.asarray(rec[key], float)
        times.append(t)
        signals.append(sig)
    if max(float(np.ptp(s['armature_voltage'])) for s in signals) < 0.05:
        raise InsufficientDataError('no excitation: the armature voltage is constant; apply duty steps')
    unknown = set(voltage_in) - set(FULL_STATE_TARGETS)
    if unknown:
        raise AeropendError(f'voltage_in names unknown equations {sorted(unknown)}; use {FULL_STATE_TARGETS}')
    if terms is not None:
        equations = [Equation(n, tuple(terms)) for n in FULL_STATE_TARGETS]
    else:
        equations = _default_full_state_equations(tuple(sorted(voltage_in)))
    options = {'threshold': 'auto', 'significance': FULL_STATE_SIGNIFICANCE}
    options.update(wsindy_options)
    result = fit_weak_sindy(times if len(times) > 1 else times[0], signals if len(signals) > 1 else signals[0],
                            equations, **options)
    values, errors = {}, {}
    rate = result['angular_rate']
    w = rate.coefficients.get('motor_speed^2', 0.0)
    se = rate.standard_errors.get('motor_speed^2', float('nan'))
    g2 = parameters.gear_ratio ** 2
    values['thrust_coefficient'] = w * g2 / parameters.lever_per_inertia
    errors['thrust_coefficient'] = se * g2 / parameters.lever_per_inertia
    values['lever_per_inertia_times_thrust_coefficient'] = w * g2
    errors['lever_per_inertia_times_thrust_coefficient'] = se * g2
    values['gravity_stiffness'] = -rate.coefficients.get('sin(angle)', 0.0)
    errors['gravity_stiffness'] = rate.standard_errors.get('sin(angle)', float('nan'))
    values['damping'] = -rate.coefficients.get('angular_rate', 0.0)
    errors['damping'] = rate.standard_errors.get('angular_rate', float('nan'))
    cur = result['armature_current']
    wv = cur.coefficients.get('armature_voltage', 0.0)
    if wv > 0:
        la = 1.0 / wv
        cc, ce = cur.coefficients, cur.standard_errors
        rel_v = ce['armature_voltage'] / wv
        values['armature_inductance'] = la
        errors['armature_inductance'] = la * rel_v
        values['armature_resistance'] = -cc.get('armature_current', 0.0) * la
        errors['armature_resistance'] = abs(values['armature_resistance']) * math.hypot(
            ce.get('armature_current', 0.0) / (abs(cc.get('armature_current', 0.0)) or 1.0), rel_v)
        values['back_emf_constant'] = -cc.get('motor_speed', 0.0) * la
        errors['back_emf_constant'] = abs(values['back_emf_constant']) * math.hypot(
            ce.get('motor_speed', 0.0) / (abs(cc.get('motor_speed', 0.0)) or 1.0), rel_v)
    return FullStateFit(values, errors, result)

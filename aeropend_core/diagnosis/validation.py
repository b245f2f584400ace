"""Checks of a fitted model beyond its held-out error, in the way MATLAB's ``compare``/``resid`` users judge one.

- :func:`validate`: the fitted model on a second record it never saw (MATLAB ``compare`` with validation data):
  free-run simulation from an initial state estimated on the record's first second, fit %, residual statistics and
  the k-step prediction error.
- :func:`simulation_band`: the held-out simulated angle's +-2 sigma band from the parameter covariance, by
  propagating sigma points (the unscented transform) through the simulator.
- :func:`prediction_points`: the k-step-ahead predictions on the held-out part (the number on the report's card,
  as points to plot).
- :func:`residual_correlations`: residual autocorrelation and residual-input cross-correlation to long lags (5 s)
  with their 99 % bands, the cross-correlation's band from the effective sample count.

Angles in rad, times in s, parameters SI.
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field, replace

import numpy as np

from aeropend_core.diagnosis.compare import (PREDICTION_HORIZON, Comparison, PreparedRecord,
                                             _heldout_simulation, _k_step_prediction, excess_error, fit_percent,
                                             prepare)
from aeropend_core.diagnosis.output_error import STRIDE, SegmentedData, fit_output_error
from aeropend_core.errors import AeropendError

#: Longest lag of the residual correlations [s] (MATLAB resid's 25 samples are 0.1 s here: too short for a rod
#: that swings at ~1 Hz).
LONG_LAG_SECONDS = 5.0

#: z of the two-sided 99 % band of a correlation estimate.
Z99 = 2.58

#: Head of the record whose data estimate the initial state of a free-run simulation [s] (as compare's held-out).
INITIAL_SECONDS = 1.0


@dataclass
class Validation:
    """The fitted model simulated on a second record (validation data). Angles in rad.

    Attributes
    ----------
    source : str
        Name of the validation record.
    effects : tuple of str
        Effects of the model that was validated (nominal + these).
    fit_percent : float [%]
        NRMSE fit of the free-run simulated angle, 100 (1 - ||y - y_sim|| / ||y - mean y||), as MATLAB compare.
    rms_error, noise_rms : float [rad]
        RMS of measured - simulated angle; RMS of the record's angle noise (estimated from the record itself).
    residual_mean, residual_std : float [rad]
        Mean and standard deviation of the residual (a mean far from 0: an offset the model lacks).
    prediction_rms : float [rad]
        RMS error of the `prediction_horizon`-ahead prediction restarted from the measured state.
    prediction_horizon : float [s]
        Horizon of that prediction.
    samples : int
        Residual samples the numbers use.
    duration : float [s]
        Length of the validation record.
    time, angle, simulated : ndarray, shape (n,) [s, rad, rad]
        The record's time and measured angle, and the simulated angle (NaN where not simulated).
    notes : list of str
        What was done differently from the fitting record, and doubts.
    """

    source: str
    effects: tuple[str, ...]
    fit_percent: float
    rms_error: float
    noise_rms: float
    residual_mean: float
    residual_std: float
    prediction_rms: float
    prediction_horizon: float
    samples: int
    duration: float
    time: np.ndarray = field(repr=False)
    angle: np.ndarray = field(repr=False)
    simulated: np.ndarray = field(repr=False)
    notes: list[str] = field(default_factory=list)

    @property
    def excess_error(self) -> float:
        """Model error beyond the validation record's noise [rad]."""
        return excess_error(self.rms_error, self.noise_rms)

    def to_dict(self) -> dict:
        """The numbers (no traces) for JSON, SI units in the key names."""
        def number(value: float) -> float | None:
            return float(value) if np.isfinite(value) else None
        return {'source': self.source, 'model_effects': list(self.effects),
                'fit_percent': number(self.fit_percent), 'rms_error_rad': number(self.rms_error),
                'noise_rms_rad': number(self.noise_rms), 'excess_error_rad': number(self.excess_error),
                'residual_mean_rad': number(self.residual_mean), 'residual_std_rad': number(self.residual_std),
                'prediction_rms_rad': number(self.prediction_rms), 'prediction_horizon_s': self.prediction_horizon,
                'residual_samples': self.samples, 'duration_s': self.duration, 'notes': list(self.notes),
                'definition': 'free-run simulation of the whole record from an initial state estimated on its '
                              f'first {INITIAL_SECONDS:g} s; fit % = 100 (1 - |y - y_sim| / |y - mean y|)'}


def _whole_record(prep: PreparedRecord) -> PreparedRecord:
    """A copy of `prep` whose held-out part is the whole record (its training part is left as it was, unused)."""
    whole = copy.copy(prep)
    whole.split = 0
    whole.heldout = SegmentedData(prep.voltage, prep.current, prep.angle, prep.gaps.pieces(0, len(prep.time)),
                                  prep.sample_time, prep.gate_voltage, prep.valid)
    return whole


def validate(comparison: Comparison, fitted_on: PreparedRecord, recording, source: str = '') -> Validation:
    """Simulate a fitted model on a second record and score it (MATLAB ``compare`` with validation data).

    Parameters
    ----------
    comparison : Comparison [-]
        The fitted model (e.g. ``diagnosis.current``); its parameters are used as they are (nothing is refitted
        except the initial state on the record's first second and, as for any record, the motor observer that
        turns Va and Ia into the thrust input).
    fitted_on : PreparedRecord [-]
        The record it was fitted on (says whether the thrust input came from the motor observer).
    recording : Recording [-]
        The validation record: armature_voltage [V], armature_current [A], angle [rad], at least 20 s.
    source : str [-]
        Its name, for the report.

    Returns
    -------
    Validation
        Fit %, residual statistics, the k-step prediction error and the traces.

    Raises
    ------
    AeropendError
        The record cannot be used (too short, no excitation, missing columns): the message says why.
    """
    prep = prepare(recording, use_motor_observer=fitted_on.motor is not None)
    notes = []
    parameters = dict(comparison.parameters)
    if fitted_on.motor is not None:
        if prep.motor is None:
            # the model's thrust input was the observer's back-EMF (R = 0 in the pendulum model); without an observer
            # here, the equivalent input is Va - Rm Ia with the fitting record's observer resistance
            parameters['armature_resistance'] = fitted_on.motor.parameters['motor_resistance']
            notes.append('the motor observer could not explain this record\'s current; its thrust input is '
                         f'Va - Rm Ia with Rm = {parameters["armature_resistance"]:.4g} Ohm from the fitting record '
                         '(expect a higher error floor)')
        else:
            notes.append('thrust input: the back-EMF of a motor observer fitted to this record\'s own Va and Ia '
                         '(an input estimate, as on the fitting record; the pendulum parameters are not refitted)')
    whole = _whole_record(prep)
    fit = replace(comparison.fit, parameters=parameters)
    simulated = _heldout_simulation(whole, fit)
    index = whole.heldout.residual_index
    residual = whole.angle[index] - simulated[index]
    if not np.all(np.isfinite(residual)):
        raise AeropendError(f'{source or "the validation record"}: the fitted model does not simulate over it (the '
                            'simulation diverged); check that it comes from the same rig')
    predicted_index, predicted = _k_step_prediction(whole, fit, PREDICTION_HORIZON)
    prediction_rms = float(np.sqrt(np.mean((whole.angle[predicted_index] - predicted) ** 2))) \
        if predicted.size else float('nan')
    if prep.findings:
        notes += [f'data quality: {f.message}' for f in prep.findings]
    return Validation(source=source or recording.source or 'validation record', effects=tuple(comparison.effects),
                      fit_percent=fit_percent(whole.angle[index], simulated[index]),
                      rms_error=float(np.sqrt(np.mean(residual ** 2))), noise_rms=prep.noise_rms,
                      residual_mean=float(np.mean(residual)), residual_std=float(np.std(residual)),
                      prediction_rms=prediction_rms, prediction_horizon=PREDICTION_HORIZON, samples=int(index.size),
                      duration=prep.duration, time=prep.time, angle=prep.angle, simulated=simulated, notes=notes)


# -- the simulated angle's band from the parameter covariance ---------------------------------------------------------

@dataclass
class Band:
    """The held-out simulated angle with its +-2 sigma band [rad], shape (n,) each (NaN where not simulated)."""

    simulated: np.ndarray
    low: np.ndarray
    high: np.ndarray
    points: int
    method: str


def _covariance(fit) -> tuple[list[str], np.ndarray]:
    names = [n for n in fit.free_names if np.isfinite(fit.standard_errors.get(n, np.nan))
             and fit.standard_errors.get(n, 0.0) > 0]
    keep = [list(fit.free_names).index(n) for n in names]
    sigma = np.array([fit.standard_errors[n] for n in names])
    correlation = np.asarray(fit.correlation, dtype=float)
    if correlation.shape != (len(fit.free_names),) * 2:
        correlation = np.eye(len(fit.free_names))
    correlation = np.nan_to_num(correlation[np.ix_(keep, keep)])
    np.fill_diagonal(correlation, 1.0)
    return names, correlation * np.outer(sigma, sigma)


def simulation_band(prep: PreparedRecord, comparison: Comparison) -> Band:
    """The held-out free-run simulation with a +-2 sigma band from the parameter covariance (unscented transform).

    The 2p sigma points theta +- sqrt(p) L_i (L the Cholesky factor of the covariance of the p free parameters:
    HAC standard errors and their correlation) are simulated from the same initial state (the one estimated on
    the held-out part's first second); the band is the nominal simulation +- 2 sqrt(sum_i (y_i - y)^2 / 2p). It shows
    how far the parameters' uncertainty moves the output, not the measurement noise (add that on top).

    Parameters
    ----------
    prep : PreparedRecord [-]
        The record the model was fitted on.
    comparison : Comparison [-]
        The fitted model.

    Returns
    -------
    Band
        simulated, low, high [rad], shape (n,), and the method in words.
    """
    fit = comparison.fit
    structure = fit.structure
    nominal = comparison.evaluation.simulated
    heldout = np.full(len(prep.time), np.nan)
    index = prep.heldout.residual_index
    heldout[index] = nominal[index]
    names, covariance = _covariance(fit)
    if not names:
        return Band(heldout, heldout, heldout, 0, 'no parameter with a finite standard error: no band')
    values, vectors = np.linalg.eigh(covariance)
    root = vectors * np.sqrt(np.clip(values, 0.0, None))          # covariance = root root^T (PSD-safe)
    p = len(names)
    head = int(round(INITIAL_SECONDS / prep.sample_time))
    head_data = SegmentedData(prep.voltage, prep.current, prep.angle,
                              [(a, min(b, a + head)) for a, b in prep.heldout.segments], prep.sample_time,
                              prep.gate_voltage, prep.valid)
    initial = fit_output_error(head_data, structure, dict(fit.parameters), fixed=dict(fit.parameters),
                               max_iterations=30).initial_states
    rows = []
    for sign in (1.0, -1.0):
        for i in range(p):
            shifted = dict(fit.parameters)
            for name, delta in zip(names, sign * math.sqrt(p) * root[:, i]):
                shifted[name] = shifted[name] + float(delta)
            rows.append(structure.row(shifted))
    runs = prep.heldout.simulate(structure, np.array(rows), np.repeat(initial[None], len(rows), axis=0))
    runs = runs[np.all(np.isfinite(runs[:, index]), axis=1)]
    spread = np.sqrt(np.mean((runs - heldout) ** 2, axis=0)) if len(runs) else np.full_like(heldout, np.nan)
    method = (f'{len(runs)} of {2 * p} sigma points (unscented transform, &theta; &plusmn; &radic;{p}&middot;L) of the '
              f'{p} free parameters\' covariance, simulated from the same initial state')
    return Band(heldout, heldout - 2 * spread, heldout + 2 * spread, len(runs), method)


def prediction_points(prep: PreparedRecord, comparison: Comparison,
                      horizon: float = PREDICTION_HORIZON) -> tuple[np.ndarray, np.ndarray]:
    """The `horizon`-ahead predictions on the held-out part: (sample indices, predicted angle [rad])."""
    return _k_step_prediction(prep, comparison.fit, horizon)


# -- residual correlations to long lags --------------------------------------------------------------------------------

@dataclass
class Correlations:
    """Residual autocorrelation (lags 0..L) and residual-input cross-correlation (lags -L..L), normalised.

    ``auto_band`` is 2.58/sqrt(N) (white residual under the null); ``cross_band`` is 2.58/sqrt(N_eff) with Bartlett's
    N_eff = N / sum_k r_rr(k) r_uu(k): a correlated residual and a correlated input make chance cross-correlations
    larger than for white data.
    """

    lag_seconds: np.ndarray
    autocorrelation: np.ndarray
    cross_lag_seconds: np.ndarray
    cross_correlation: np.ndarray
    auto_band: float
    cross_band: float
    samples: int
    effective_samples: float


def _correlation_fft(a: np.ndarray, b: np.ndarray, lags: int) -> np.ndarray:
    """Normalised cross-correlation of a(t) with b(t - lag) for lag in [-lags, lags], by FFT (the same numbers as
    :func:`aeropend_core.diagnosis.compare._correlation`, in O(n log n) instead of O(n lags))."""
    from scipy.signal import correlate

    a = a - a.mean()
    b = b - b.mean()
    scale = math.sqrt(float(np.dot(a, a) * np.dot(b, b))) or 1.0
    full = correlate(a, b, mode='full', method='fft')
    zero = len(b) - 1
    return full[zero - lags:zero + lags + 1] / scale


def residual_correlations(prep: PreparedRecord, comparison: Comparison,
                          max_lag_seconds: float = LONG_LAG_SECONDS) -> Correlations:
    """Correlations of the held-out simulation residual with itself and with the thrust input e|e| to long lags.

    The residual is taken every STRIDE samples (where the simulation lands); lags reach `max_lag_seconds` or a third
    of the held-out part, whichever is shorter.
    """
    index = prep.heldout.residual_index
    residual = prep.angle[index] - comparison.evaluation.simulated[index]
    e = prep.voltage - comparison.parameters.get('armature_resistance', 0.0) * prep.current
    thrust = (e * np.abs(e))[index]
    n = residual.size
    step = STRIDE * prep.sample_time
    lags = max(1, min(int(round(max_lag_seconds / step)), n // 3))
    cross = _correlation_fft(residual, thrust, lags)
    auto = _correlation_fft(residual, residual, lags)
    input_auto = _correlation_fft(thrust, thrust, lags)
    inflation = float(np.sum(auto * input_auto))
    effective = float(np.clip(n / inflation, 1.0, n)) if inflation > 0 else float(n)
    lag_axis = np.arange(-lags, lags + 1) * step
    return Correlations(lag_seconds=lag_axis[lags:], autocorrelation=auto[lags:], cross_lag_seconds=lag_axis,
                        cross_correlation=cross, auto_band=Z99 / math.sqrt(n), cross_band=Z99 / math.sqrt(effective),
                        samples=n, effective_samples=effective)


__all__ = ['Band', 'Correlations', 'Validation', 'prediction_points', 'residual_correlations', 'simulation_band',
           'validate', 'LONG_LAG_SECONDS']

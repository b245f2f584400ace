"""Identify a recording's equations in one call: what ``aeropend identify`` prints, as a result object.

:func:`identify_record` composes the pipeline the verb runs on a loaded recording: the weak-form fit of the pendulum
(on the pieces between gaps of lost samples, the angle advanced by a calibrated filter delay), or the reduced model
when the record has no period-average armature current, or the full-state equations of a simulation; then the
held-out score and the cross-check against the output-error fit, the free-oscillation estimate and the physical
checks of the parameters. Its :class:`Identification` presents itself: :meth:`~Identification.as_text` and
:meth:`~Identification.to_dict` are byte for byte what ``aeropend identify`` and ``aeropend identify --json`` print
(the verb is a thin wrapper; bench/outputs_identical.py compares them with the tree before the move).

Examples
--------
>>> from aeropend_core.identify.record import WEAK_FORM_LOW_RATE_TIME, pieces_between_gaps
>>> import numpy as np
>>> time = np.r_[np.arange(0.0, 2.0, 0.002), np.arange(2.5, 4.0, 0.002)]      # s: one gap of lost samples
>>> pieces_between_gaps(time)                                                  # sample ranges fitted together
[(0, 1000), (1000, 1750)]
>>> round(1.0 / WEAK_FORM_LOW_RATE_TIME, 1)       # Hz: below this rate the weak-form numbers carry a bias warning
326.7
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from aeropend_core.errors import AeropendError

if TYPE_CHECKING:       # annotations only
    from aeropend_core.identify.plausibility import FreeOscillation
    from aeropend_core.io.recording import Recording

#: Sample time [s] above which the weak-form fit is said to be biased (measured in bench/rate_sweep.py: at 245 Hz
#: gravity_stiffness ~9 % low, at 122 Hz ~30 %, at 24.5 Hz a thrust gain of the wrong sign).
WEAK_FORM_LOW_RATE_TIME = 1.5 / 490.0
#: The weak form's largest measured relative error of (gravity_stiffness, damping, thrust_gain) per rate [Hz] over
#: seeds 11-14 (bench/lowrate_weak_form.py, 40 dB, 10-bit; bench/results/2026-11-27-lowrate/weak_form.json).
WEAK_FORM_RATE_BIAS = ((245.0, (-0.141, -0.086, -0.191)), (98.0, (-0.444, -0.368, -0.530)),
                       (49.0, (-0.577, -0.435, -0.706)), (24.5, (-0.684, -0.487, -0.860)))
#: The models :func:`identify_record` fits (``'pendulum'`` turns into the reduced model without a current).
MODELS = ('pendulum', 'full-state')


def pieces_between_gaps(time: np.ndarray, shortest: float = 1.0) -> list[tuple[int, int]]:
    """Sample ranges between gaps (a step over 1.5 median steps) at least `shortest` [s] long (all: no gap).

    Parameters
    ----------
    time : ndarray [s]
        Sample times.
    shortest : float [s]
        Shortest piece kept.
    """
    if time.size < 3:
        return [(0, time.size)]
    steps = np.diff(time)
    step = float(np.median(steps))
    cuts = np.flatnonzero(steps > 1.5 * step) + 1
    if cuts.size == 0 or not step > 0:
        return [(0, time.size)]
    bounds = np.concatenate(([0], cuts, [time.size]))
    return [(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:]) if (b - a) * step >= shortest]


def short_pieces(time: np.ndarray, shortest: float = 1.0) -> list[tuple[int, int, float, float]]:
    """(first, stop, t first [s], t last [s]) of each piece between gaps that :func:`pieces_between_gaps` leaves
    out (shorter than `shortest` [s])."""
    if time.size < 3:
        return []
    kept = set(pieces_between_gaps(time, shortest))
    steps = np.diff(time)
    bounds = np.concatenate(([0], np.flatnonzero(steps > 1.5 * float(np.median(steps))) + 1, [time.size]))
    return [(int(a), int(b), float(time[a]), float(time[b - 1])) for a, b in zip(bounds[:-1], bounds[1:])
            if (int(a), int(b)) not in kept]


def rate_warning(recording: Recording) -> str:
    """The doubt a low sample rate casts on the weak-form numbers, with the bias measured near that rate (empty at
    the rig's rate).

    Parameters
    ----------
    recording : Recording [-]
        Its time stamps [s] give the rate.
    """
    if len(recording) < 3:
        return ''
    step = float(np.median(np.diff(np.asarray(recording.time, dtype=float))))
    if not step > WEAK_FORM_LOW_RATE_TIME:
        return ''
    rate = 1.0 / step
    at, (gravity, damping, gain) = next((entry for entry in WEAK_FORM_RATE_BIAS if entry[0] <= rate * 1.02),
                                        WEAK_FORM_RATE_BIAS[-1])
    slower = f'; {rate:.4g} Hz is slower than any rate measured' if rate < 0.98 * WEAK_FORM_RATE_BIAS[-1][0] else ''
    return (f'at {rate:.4g} Hz ({step * 1e3:.3g} ms per sample) the weak-form fit is biased low. Measured at {at:g} '
            f'Hz on four seeded simulations, as far off as gravity_stiffness {gravity * 100:+.0f} %, damping '
            f'{damping * 100:+.0f} %, thrust_gain {gain * 100:+.0f} %{slower} (bench/lowrate_weak_form.py); these '
            'parameters are not trustworthy. '
            'Use `aeropend diagnose` (output error with a motor observer): at 24.5-98 Hz its parameters were within '
            'the tolerances of docs/log-import.md')


def angle_filter_effect() -> str:
    """The name of the catalog's built-in angle filter (its measurement filter): the effect a calibration file's
    ``angle_filter_delay`` [s] holds, and the key of the filter's note in ``aeropend identify --json``."""
    from aeropend_core.model.effects import CATALOG, MEASUREMENT_FILTER
    return next(name for name, effect in CATALOG.items() if effect.builtin and effect.kind == MEASUREMENT_FILTER)


def flag_lines(text: str, warnings: dict[str, str]) -> str:
    """`text` with each failing parameter's warning at the end of its line (``  name = value ...``)."""
    lines = []
    for line in text.splitlines():
        name = line.strip().split(' = ')[0] if ' = ' in line and line.startswith('  ') else ''
        lines.append(line + (f'   !! {warnings[name]}' if name in warnings else ''))
    return '\n'.join(lines)


@dataclass
class Identification:
    """Outcome of :func:`identify_record`: the fit with its checks, presenting itself as ``aeropend identify`` does.

    Parameters
    ----------
    source : str [-]
        The record's name, as the text's first line shows it.
    model : str [-]
        ``'pendulum'``, ``'full-state'`` or the reduced model's name (``signals.reduced.REDUCED_MODEL``).
    recording : Recording [-]
        The record fitted (samples, time stamps [s], the data-quality findings).
    fit : PendulumFit, FullStateFit or ReducedFit [-]
        The fit: ``parameters`` SI with ``standard_errors`` (1 sigma).
    independent : FreeOscillation [-]
        The free-oscillation estimate (frequency [rad/s]) the parameters are checked against.
    warnings : dict of str -> str [-]
        Parameters failing a physical check -> why (the verdict ``model_does_not_fit`` when any).
    rate_warning : str [-]
        The low-rate doubt on every weak-form number (empty at the rig's rate).
    pieces : list of (int, int) [samples]
        The pieces between gaps of lost samples the weak form was fitted on.
    filter_note : dict or None [-]
        The calibrated angle filter: ``delay`` [s], where it came from, the correction applied.
    check : CrossCheck or None [-]
        The held-out score and the cross-check against the output-error fit (None when not run).
    check_note : str or None [-]
        Why the cross-check is missing, when it failed.
    notes : list of str [-]
        What the verb says on standard error (gaps, the filter's advance, the reduced model, the low rate).
    """

    source: str
    model: str
    recording: Any
    fit: Any
    independent: FreeOscillation
    warnings: dict[str, str]
    rate_warning: str = ''
    pieces: list[tuple[int, int]] = field(default_factory=list)
    filter_note: dict | None = None
    check: Any = None
    check_note: str | None = None
    notes: list[str] = field(default_factory=list)

    @property
    def reduced(self) -> bool:
        """Whether the reduced model was fitted (no period-average armature current)."""
        return self.model not in MODELS

    @property
    def verdict(self) -> str:
        """``'model_does_not_fit'`` when a parameter fails a physical check, else ``'parameters_plausible'``."""
        return 'model_does_not_fit' if self.warnings else 'parameters_plausible'

    def summary(self) -> dict:
        """Model, verdict, parameters (SI) with their 1-sigma standard errors, and every doubt on them:
        ``parameter_warnings`` (failed checks) and ``parameters_doubt`` (a low rate; empty when none)."""
        return {'model': self.model, 'verdict': self.verdict, 'samples': len(self.recording),
                'parameters': dict(self.fit.parameters), 'standard_errors': dict(self.fit.standard_errors),
                'parameter_warnings': dict(self.warnings), 'parameters_doubt': self.rate_warning}

    def to_dict(self) -> dict:
        """Exactly what ``aeropend identify --json`` prints (plain JSON types, NaN as null)."""
        from aeropend_core.present.json_output import finite_json
        from aeropend_core.signals.quality import findings_to_json
        fit, recording = self.fit, self.recording
        if self.reduced:
            from aeropend_core.model.effects import parameter_unit
            from aeropend_core.signals.reduced import IDENTIFIABLE, MAP_PARAMETERS, NOT_IDENTIFIABLE
            return finite_json({
                'model': self.model, 'parameters': finite_json(fit.parameters),
                'parameter_standard_errors': finite_json(fit.standard_errors),
                'units': {k: MAP_PARAMETERS.get(k) or parameter_unit(k) for k in fit.parameters},
                'estimator': 'output_error', 'fit_percent': fit.comparison.fit_percent,
                'rms_error': fit.comparison.rms_error, 'noise_rms': fit.comparison.noise_rms,
                'identifiable': IDENTIFIABLE, 'not_identifiable': NOT_IDENTIFIABLE,
                'samples': len(recording), 'warnings': findings_to_json(recording.findings),
                'parameter_warnings': self.warnings, 'verdict': self.verdict,
                'free_oscillation': self.independent.to_dict()})
        from aeropend_core.identify.pendulum import parameter_unit_of
        out = {
            'model': self.model,
            'coefficients': fit.result.coefficients,
            'standard_errors': fit.result.standard_errors,
            'parameters': finite_json(fit.parameters),
            'parameter_standard_errors': finite_json(fit.standard_errors),
            'units': {k: parameter_unit_of(k) for k in fit.parameters},
            'estimator': 'weak_sindy',
            'gaps': {'count': len(self.pieces) - 1, 'pieces': len(self.pieces)},
            angle_filter_effect(): self.filter_note,
            'samples': len(recording),
            'test_function_half_width': {eq.name: eq.half_width for eq in fit.result.equations},
            'warnings': findings_to_json(recording.findings),
            'cross_check': finite_json(self.check.to_dict()) if self.check is not None else self.check_note,
            'parameter_warnings': self.warnings,
            'verdict': self.verdict,
            'free_oscillation': self.independent.to_dict(),
        }
        if self.rate_warning:
            out['warnings'].append({'code': 'low_sample_rate', 'severity': 'warning', 'message': self.rate_warning})
            out['parameters_doubt'] = self.rate_warning
        return finite_json(out)

    def as_text(self) -> str:
        """Exactly what ``aeropend identify`` prints: the record, the data's doubts, the equations and parameters
        (SI, +- 1 sigma, failed checks flagged), the cross-check, the free oscillation and the verdict."""
        from aeropend_core.signals.quality import quality_lines
        recording = self.recording
        duration = len(recording) * float(np.median(np.diff(recording.time))) if len(recording) > 1 else 0.0
        lines = [f'{self.source}: {len(recording)} samples ({duration:.3g} s), model {self.model}',
                 quality_lines(recording.findings)]
        if self.reduced:
            lines.append(self.fit.format(self.warnings))
        else:
            if self.filter_note is not None:
                lines.append(f'Angle filter: delay {self.filter_note["delay"]} s, fixed from '
                             f'{self.filter_note["from"]}; {self.filter_note["correction"]}')
            if self.rate_warning:
                lines.append(f'Warning: {self.rate_warning}')
            lines.append(flag_lines(self.fit.format(), self.warnings))
            if self.rate_warning:
                lines.append(f'Warning (about every number above): {self.rate_warning}')
            lines += self.check.lines() if self.check is not None else [self.check_note] if self.check_note else []
        lines.append(self.independent.describe())
        if self.warnings:
            from aeropend_core.identify.plausibility import verdict_line
            lines.append('Verdict: ' + verdict_line(self.warnings))
        return '\n'.join(lines)

    def as_html(self) -> str:
        """:meth:`as_text` as a self-contained HTML fragment (``<section>``, text escaped, no link)."""
        from aeropend_core.present.results_text import text_html
        return text_html(self.as_text(), f'aeropend identify: {self.source}', 'aeropend-identification')


def identify_record(recording: Recording, *, model: str = 'pendulum', effects: Sequence[str] = (),
                    calibration=None, calibration_source: str = '', weak_only: bool = False, source: str = 'FILE',
                    note: Callable[[str, bool], None] | None = None) -> Identification:
    """Identify a loaded recording's equations as ``aeropend identify`` does (module docstring).

    Parameters
    ----------
    recording : Recording [-]
        Through the data-quality gate (``load_recording``), cut to the range wanted.
    model : str [-]
        ``'pendulum'`` (the reduced model when the record has no period-average armature current) or
        ``'full-state'`` (needs the simulator's motor_speed and angular_rate).
    effects : sequence of str [-]
        Catalog effects with a weak form added as candidate terms (pendulum model).
    calibration : MeasurementChain, optional [-]
        The rig's measurement chain (``rig.calibration.read_measurement_chain``): the angle is advanced by its
        ``angle_filter_delay`` [s] before the fit (pendulum model).
    calibration_source : str [-]
        Where `calibration` came from (its file), said in the result.
    weak_only : bool [-]
        Skip the held-out score and the cross-check against the output-error fit.
    source : str [-]
        The record's name in the text and in the next commands suggested.
    note : callable(str, bool), optional [-]
        Called with each message for standard error as it arises, and whether it is a warning (said also when
        quiet) or a note; the result keeps them in ``notes`` too.

    Returns
    -------
    Identification
        The fit with its checks; ``as_text()`` and ``to_dict()`` are what ``aeropend identify`` and ``--json``
        print.

    Raises
    ------
    AeropendError
        A model that does not fit the record (full-state without simulator columns, calibration on the reduced
        or full-state model), or no piece between gaps of 1 s or more.
    """
    if model not in MODELS:
        raise AeropendError(f'model {model!r}: choose one of {", ".join(MODELS)}')
    notes: list[str] = []

    def say(message: str, warning: bool = False) -> None:
        notes.append(message)
        if note is not None:
            note(message, warning)

    from aeropend_core.identify.pendulum import identify_full_state, identify_pendulum
    pieces = pieces_between_gaps(np.asarray(recording.time, dtype=float))
    chain = calibration
    if chain is not None and model != 'pendulum':
        raise AeropendError('--calibration applies to the pendulum model (the full-state model uses simulator '
                            'truth columns, which have no sensor filter)')
    if model == 'pendulum' and 'armature_current' not in recording.signals:
        if chain is not None:
            raise AeropendError('--calibration is not supported by the reduced model (no armature current); use '
                                'aeropend diagnose --calibration, which holds the angle filter in the model')
        return _identify_reduced(recording, effects, source, say, notes)
    filter_note = None
    if model == 'pendulum':
        names = ('armature_voltage', 'armature_current', 'angle')
        columns = [np.asarray(recording.signal(name), dtype=float) for name in names]
        duty = recording.signals.get('duty')
        if chain is not None and chain.angle_filter_delay:
            from aeropend_core.signals.measurement_chain import advance_angle
            time_all = np.asarray(recording.time, dtype=float)
            advanced = np.full(time_all.size, np.nan)
            for a, b in pieces:       # within each piece between gaps (never across a gap)
                keep, values = advance_angle(time_all[a:b], columns[2][a:b], chain.angle_filter_delay)
                advanced[a:b][keep] = values
            columns[2] = advanced
            pieces = [(a, b - int(np.count_nonzero(np.isnan(advanced[a:b])))) for a, b in pieces]
            filter_note = {'delay': chain.angle_filter_delay, 'from': f'calibration file {calibration_source}',
                           'correction': 'angle advanced by the delay (first-order inverse of the RC low-pass)'}
            say(f'angle advanced by the angle filter delay {chain.angle_filter_delay * 1e3:.2f} ms fixed from '
                f'calibration file {calibration_source}')
        elif chain is not None:
            filter_note = {'delay': chain.angle_filter_delay, 'from': f'calibration file {calibration_source}',
                           'correction': 'none (no filter stated)' if chain.angle_filter_delay is None else
                           'none (no filter on the angle)'}
        if not pieces:
            raise AeropendError(f'{source}: no piece between its gaps of lost samples lasts 1 s or more; nothing '
                                'to fit')
        whole = pieces == [(0, len(recording.time))]
        if not whole or filter_note and filter_note['delay']:
            # lost samples: the weak form is fitted on the pieces between the gaps, together (also the single
            # piece trimmed by the filter's delay, or the one piece left when a short one after a gap is dropped)
            cut = [[c[a:b] for a, b in pieces] for c in [np.asarray(recording.time, dtype=float), *columns]]
            fit = identify_pendulum(*cut, duty=None if duty is None else [duty[a:b] for a, b in pieces],
                                    effects=effects)
            if len(pieces) > 1:
                say(f'{len(pieces) - 1} gap(s) of lost samples in the time stamps: fitted on the {len(pieces)} '
                    'pieces between them together')
            dropped = short_pieces(np.asarray(recording.time, dtype=float))
            if dropped:
                say('; '.join(f'{b - a} sample(s) from t = {t0:.3f} to {t1:.3f} s' for a, b, t0, t1 in dropped) +
                    ' between gaps of lost samples: shorter than 1 s, not fitted')
        else:
            fit = identify_pendulum(recording.time, *columns, duty=duty, effects=effects)
    else:
        fit = identify_full_state(recording)
    check, check_note = None, None
    if model == 'pendulum' and not weak_only:
        # one answer per record: the weak form scored as diagnose scores, and compared with the output-error fit
        from aeropend_core.diagnosis.agreement import cross_check
        fixed = ({angle_filter_effect(): chain.angle_filter_delay} if chain is not None and chain.angle_filter_delay
                 else {})
        try:
            check = cross_check(recording, fit, tuple(effects) + tuple(fixed), source, fixed)
        except AeropendError as error:       # too short or too flat for the output-error fit: say so, keep the fit
            check_note = f'no held-out score or output-error cross-check: {error}'
        except (ValueError, FloatingPointError, np.linalg.LinAlgError) as error:      # the fit failed numerically
            check_note = (f'no held-out score or output-error cross-check: the output-error fit failed '
                          f'({type(error).__name__}: {error}); run aeropend diagnose {source} to see why')
    from aeropend_core.identify.plausibility import check_parameters, free_oscillation
    independent = free_oscillation(recording.time, recording.signal('angle'), recording.signal('armature_voltage'))
    fitted = set(fit.parameters) - {'armature_resistance_from_current_square'}
    warnings = check_parameters(fit.parameters, fit.standard_errors, independent, fitted)
    low_rate = rate_warning(recording)
    if low_rate:
        say(f'warning: {low_rate}', True)
    return Identification(source=source, model=model, recording=recording, fit=fit, independent=independent,
                          warnings=warnings, rate_warning=low_rate, pieces=pieces, filter_note=filter_note,
                          check=check, check_note=check_note, notes=notes)


def _identify_reduced(recording, effects, source, say, notes) -> Identification:
    """The pendulum model without a period-average current: the reduced model (docs/reduced-model.md)."""
    from aeropend_core.diagnosis.reduced_fit import identify_reduced
    from aeropend_core.identify.plausibility import check_parameters, free_oscillation
    from aeropend_core.signals.reduced import REDUCED_MODEL
    say('no period-average armature current in the record: fitting the reduced model (thrust from Va through the '
        'motor map; output error, about a minute)', True)
    fit = identify_reduced(recording, effects)
    prep = fit.prepared
    independent = free_oscillation(recording.time, recording.signal('angle'), recording.signal('armature_voltage'),
                                   None if prep is None else prep.step_indices)
    warnings = check_parameters(fit.parameters, fit.standard_errors, independent)
    return Identification(source=source, model=REDUCED_MODEL, recording=recording, fit=fit, independent=independent,
                          warnings=warnings, notes=notes)


__all__ = ['Identification', 'identify_record', 'pieces_between_gaps', 'short_pieces', 'rate_warning', 'flag_lines',
           'angle_filter_effect',
           'WEAK_FORM_LOW_RATE_TIME', 'WEAK_FORM_RATE_BIAS', 'MODELS']

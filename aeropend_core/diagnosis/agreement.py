"""One answer per record: do the weak form (``aeropend identify``) and the output-error fit (``diagnose``) agree?

The two estimators see the same record differently. The weak form regresses the integrated-by-parts pendulum
equation on the measured Va, Ia and angle: fast, but it has no term for the effects it cannot write in that form
(dry friction, drag, a thrust lag, a dead zone, an angle filter) and its thrust regressors carry the noise of Ia.
The output-error fit simulates the angle from the inputs and is judged on held-out data. When their numbers for the
same parameter differ by more than :data:`AGREEMENT_SIGMA` combined standard errors, a user must be told which
to believe and why, never shown two values silently.
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from aeropend_core.model.names import NOMINAL_PARAMETERS

#: Two estimates disagree when |a - b| exceeds this many combined standard errors sqrt(sa^2 + sb^2) (two honest
#: estimates of one value cross it ~0.3 % of the time; a weak-form bias of a few sigma does not hide behind it).
AGREEMENT_SIGMA = 3.0
#: The parameters both estimators report with the same meaning.
COMPARED = ('gravity_stiffness', 'damping', 'thrust_gain', 'armature_resistance')


@dataclass
class Agreement:
    """Result of :func:`compare_estimators`.

    Attributes
    ----------
    agree : bool
        No compared parameter differs by more than :data:`AGREEMENT_SIGMA` combined sigma.
    disagreeing : list of str
        The parameters that do.
    separation : dict of str -> float
        |a - b| / sqrt(sa^2 + sb^2) per compared parameter [-].
    lines : list of str
        Plain sentences for a user: the values side by side, why they differ and the command to run.
    """

    agree: bool
    disagreeing: list[str] = field(default_factory=list)
    separation: dict[str, float] = field(default_factory=dict)
    lines: list[str] = field(default_factory=list)


def compare_estimators(weak_values: Mapping[str, float], weak_errors: Mapping[str, float],
                       output_values: Mapping[str, float], output_errors: Mapping[str, float],
                       effects: Sequence[str] = (), data: str = 'FILE') -> Agreement:
    """Compare the weak-form and the output-error estimates of the parameters they share.

    Parameters
    ----------
    weak_values, weak_errors : mapping of str -> float [SI]
        The weak form's parameters and 1-sigma (:class:`aeropend_core.identify.pendulum.PendulumFit`).
    output_values, output_errors : mapping of str -> float [SI]
        The output-error fit's reported parameters and 1-sigma (with the motor observer's armature resistance).
    effects : sequence of str [-]
        Effects in the output-error model (named in the explanation when the weak form cannot carry them).
    data : str [-]
        The record's path for the suggested command.

    Returns
    -------
    Agreement
    """
    from aeropend_core.identify.pendulum import weak_form_effects
    separation, disagreeing, pairs = {}, [], []
    for name in COMPARED:
        a, b = weak_values.get(name), output_values.get(name)
        sa, sb = weak_errors.get(name, math.nan), output_errors.get(name, math.nan)
        if a is None or b is None or not all(math.isfinite(v) for v in (a, b)):
            continue
        combined = math.hypot(sa if math.isfinite(sa) else 0.0, sb if math.isfinite(sb) else 0.0)
        distance = abs(a - b) / combined if combined > 0 else (0.0 if a == b else math.inf)
        separation[name] = distance
        if distance > AGREEMENT_SIGMA:
            disagreeing.append(name)
            unit = NOMINAL_PARAMETERS.get(name, ('',))[0]
            pairs.append(f'{name} {a:.4g} +- {sa:.2g} (weak form) vs {b:.4g} +- {sb:.2g} {unit} (output error), '
                         f'{distance:.1f} sigma apart')
    if not disagreeing:
        return Agreement(True, [], separation, [
            f'The weak form and the output-error fit agree within {AGREEMENT_SIGMA:g} sigma on '
            f'{", ".join(separation) or "no shared parameter"}.'])
    missing = [name for name in effects if name not in weak_form_effects()]
    if missing:
        why = (f'the output-error model has {", ".join(missing)}, which the weak form cannot write (it needs the '
               f'rate inside a nonlinearity or the thrust history), so the weak form folds it into the nominal terms')
    else:
        why = ('the weak form has no term for effects it cannot write (dry friction, drag, thrust lag, dead zone, '
               'angle filter) and its thrust terms carry the noise of Ia; the output-error fit simulates the angle '
               'and is checked on held-out data')
    lines = ['The weak form and the output-error fit DISAGREE: ' + '; '.join(pairs) + '.',
             f'Why: {why}. Trust the output-error numbers (their held-out fit is stated) and find what is missing '
             f'with: aeropend diagnose {data}']
    return Agreement(False, disagreeing, separation, lines)


@dataclass
class CrossCheck:
    """Result of :func:`cross_check`: the weak form's free-run score and its agreement with the output-error fit.

    Attributes
    ----------
    fit_percent : float [%]
        Free-run fit of the weak-form model (refitted on the training part) on the held-out part, the diagnosis's
        definition (NRMSE fit as MATLAB ``compare``).
    rms_error, noise_rms, error_beyond_noise : float [rad]
        Its held-out RMS error, the angle's noise and sqrt(max(rms^2 - noise^2, 0)) (as ``diagnose`` reports).
    output_values, output_errors : dict of str -> float [SI]
        The output-error fit's parameters and 1-sigma (same model structure, motor observer's R).
    agreement : Agreement
    """

    fit_percent: float
    rms_error: float
    noise_rms: float
    error_beyond_noise: float
    output_values: dict[str, float]
    output_errors: dict[str, float]
    agreement: Agreement
    output_fit_percent: float = math.nan
    output_error_beyond_noise: float = math.nan

    def lines(self) -> list[str]:
        """The text for a user: the score on the diagnosis's scale, then the agreement sentences."""
        if math.isinf(self.rms_error):
            weak = (f'Held-out free run of the weak-form model (refitted on the first {TRAIN_SHARE:.0%}, simulated '
                    f'on the rest, as diagnose scores): it diverges, so it has no fit score; its numbers do not make '
                    f'a model that runs on this record (noise {self.noise_rms * 1e3:.2f} mrad)')
        else:
            weak = (f'Held-out free-run fit of the weak-form model (refitted on the first {TRAIN_SHARE:.0%}, '
                    f'simulated on the rest, as diagnose scores): fit {self.fit_percent:.2f} %, error beyond the '
                    f'noise {self.error_beyond_noise * 1e3:.2f} mrad (rms {self.rms_error * 1e3:.2f} mrad, noise '
                    f'{self.noise_rms * 1e3:.2f} mrad)')
        return [weak,
                f'Output-error fit of the same model (diagnose\'s estimator): held-out fit '
                f'{self.output_fit_percent:.2f} %, error beyond the noise {self.output_error_beyond_noise * 1e3:.2f} '
                f'mrad', *self.agreement.lines]

    def to_dict(self) -> dict:
        """JSON form (SI, angles in rad)."""
        return {'heldout_fit_percent': self.fit_percent, 'heldout_rms_error': self.rms_error,
                'noise_rms': self.noise_rms, 'error_beyond_noise': self.error_beyond_noise,
                'output_error_parameters': self.output_values, 'output_error_standard_errors': self.output_errors,
                'output_error_heldout_fit_percent': self.output_fit_percent,
                'output_error_beyond_noise': self.output_error_beyond_noise, 'agree': self.agreement.agree,
                'disagreeing': self.agreement.disagreeing,
                'separation_sigma': self.agreement.separation, 'agreement': ' '.join(self.agreement.lines)}


#: Share of the record the weak form is refitted on for its held-out score (the diagnosis's training share).
TRAIN_SHARE = 0.75


def cross_check(recording, weak_fit, effects: Sequence[str] = (), data: str = 'FILE',
                fixed: Mapping[str, float] | None = None) -> CrossCheck:
    """Score the weak form on the diagnosis's scale and compare it with the output-error fit of the same model.

    Parameters
    ----------
    recording : Recording
        The record (Va [V], Ia [A], angle [rad]).
    weak_fit : PendulumFit
        The weak form's fit of the whole record (its numbers are the ones compared).
    effects : sequence of str [-]
        Effects in the weak-form model (those with a weak form).
    data : str [-]
        The record's path, for the suggested command.
    fixed : mapping of str -> float, optional [SI]
        Parameters held in the output-error fit (e.g. a known angle filter).

    Returns
    -------
    CrossCheck
    """
    import numpy as np

    from aeropend_core.diagnosis.compare import (_heldout_simulation, compare, excess_error, fit_percent, prepare,
                                                 ran_away)
    from aeropend_core.diagnosis.output_error import Structure
    from aeropend_core.identify.pendulum import identify_pendulum
    plain = prepare(recording, train_fraction=TRAIN_SHARE, use_motor_observer=False)
    split = plain.split
    train = identify_pendulum(plain.time[:split], plain.armature_voltage[:split], plain.armature_current[:split],
                              plain.angle[:split], effects=effects)
    structure = Structure(tuple(effects))
    values = {name: float(train.parameters.get(name, 0.0)) for name in structure.parameter_names}
    values = {k: (v if math.isfinite(v) else 0.0) for k, v in values.items()}

    class _Model:       # what the held-out simulation reads of a fit
        pass
    model = _Model()
    model.structure, model.parameters = structure, values
    simulated = _heldout_simulation(plain, model)
    index = plain.heldout.residual_index
    measured = plain.angle[index]
    heldout = simulated[index]
    # a weak-form model can be unstable as a running model (e.g. badly biased at a low sample rate): its free run
    # then grows without bound; that is said (rms inf, fit undefined), not squared into an overflow
    diverged = ran_away(measured, heldout)
    rms = math.inf if diverged else float(np.sqrt(np.mean((measured - heldout) ** 2)))
    score = float('nan') if diverged else fit_percent(measured, heldout)
    prep = prepare(recording)
    comparison = compare(prep, effects, fixed=dict(fixed or {}))
    output_values, output_errors = dict(comparison.parameters), dict(comparison.fit.standard_errors)
    if prep.motor is not None:
        output_values['armature_resistance'] = prep.motor.parameters['motor_resistance']
        output_errors['armature_resistance'] = prep.motor.standard_errors.get('motor_resistance', math.nan)
    agreement = compare_estimators(weak_fit.parameters, weak_fit.standard_errors, output_values, output_errors,
                                   effects, data)
    return CrossCheck(score, rms, plain.noise_rms, excess_error(rms, plain.noise_rms), output_values, output_errors,
                      agreement, comparison.fit_percent, excess_error(comparison.rms_error, comparison.noise_rms))


__all__ = ['AGREEMENT_SIGMA', 'COMPARED', 'TRAIN_SHARE', 'Agreement', 'CrossCheck',
           'compare_estimators', 'cross_check']

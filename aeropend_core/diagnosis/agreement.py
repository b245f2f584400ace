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


__all__ = ['AGREEMENT_SIGMA', 'COMPARED', 'Agreement', 'compare_estimators']

"""A diagnosis's parameters checked against physics (:mod:`aeropend_core.identify.plausibility`), and what the
reduced model cannot tell, written into the diagnosis itself (warnings next to the numbers, verdict, notes).
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from aeropend_core.diagnosis.verdicts import Verdict

#: Verdict of a diagnosis whose identified parameters fail a physical check.
DOES_NOT_FIT = Verdict.MODEL_DOES_NOT_FIT


def misfit_doubt(diagnosis) -> str | None:
    """The doubt a model's misfit casts on its parameters, or None when it fits within the noise.

    A model that misses the data by more than half the noise RMS beyond the noise (the diagnosis's own
    ``UNEXPLAINED_NOISE`` line) has parameters that absorb what it misses: their ± is the spread the noise alone
    would give, and says nothing of that bias.

    Parameters
    ----------
    diagnosis : Diagnosis
        A finished diagnosis; its ``current`` model is the one whose parameters are reported.

    Returns
    -------
    str or None
        One sentence (no final full stop), with the misfit in mrad.
    """
    from aeropend_core.diagnosis.compare import excess_error
    from aeropend_core.diagnosis.thresholds import UNEXPLAINED_NOISE
    current = diagnosis.current
    noise = current.noise_rms
    beyond = excess_error(current.rms_error, noise)
    if not beyond > UNEXPLAINED_NOISE * noise:
        return None
    return (f'the parameters are those of a model that misses the data by {beyond * 1e3:.2f} mrad beyond the noise '
            f'({noise * 1e3:.2f} mrad): they absorb what it misses, so they can be off by more than their +- says '
            '(the +- is the spread the noise alone gives)'
            + ('; the values with the missing effects added are given with them' if diagnosis.found else ''))


def fitted_thrust_lag(diagnosis) -> tuple[float | None, float | None, str]:
    """(thrust time constant [s], mgd/J [1/s^2] of the same fit, which fit) the diagnosis finds: from the reported
    model (selected, else current) when it carries a thrust lag, else from the strongest significant candidate that
    is one; (None, None, '') when no fit finds a lag."""
    from aeropend_core.model.effects import CATALOG, THRUST_LAG
    lag_parameters = [p.name for e in CATALOG.values() if e.kind == THRUST_LAG for p in e.parameters]
    for comparison, source in ((diagnosis.selected, 'the selected model'), (diagnosis.current, 'the model')):
        if comparison is None:
            continue
        values = comparison.parameters
        for name in lag_parameters:
            if values.get(name):
                return float(values[name]), values.get('gravity_stiffness'), source
    lags = [c for c in diagnosis.candidates if c.significant and c.comparison is not None
            and any(c.parameters.get(name) for name in lag_parameters)]
    if lags:
        best = min(lags, key=lambda c: c.delta_bic)
        value = next(best.parameters[name] for name in lag_parameters if best.parameters.get(name))
        return float(value), best.comparison.parameters.get('gravity_stiffness'), f'the {best.effect} candidate'
    return None, None, ''


def check_diagnosis(diagnosis):
    """Check `diagnosis`'s reported parameters; set ``parameter_warnings`` and ``independent`` and, when one fails,
    the verdict :data:`DOES_NOT_FIT` with the reason first in the message. Returns the diagnosis.

    Parameters
    ----------
    diagnosis : Diagnosis
        A finished diagnosis (its ``prepared`` record gives the angle and the input for the free-oscillation check).

    Returns
    -------
    Diagnosis
        The same object, updated.
    """
    from aeropend_core.identify.plausibility import check_parameters, check_premise, free_oscillation, verdict_line
    from aeropend_core.signals.reduced import NOT_IDENTIFIABLE
    prep = diagnosis.prepared
    independent = None
    if prep is not None:
        try:
            independent = free_oscillation(prep.time, prep.angle, prep.gate_voltage, prep.step_indices)
        except (ValueError, np.linalg.LinAlgError):
            independent = None
    if independent is not None:
        independent = check_premise(independent, *fitted_thrust_lag(diagnosis))
    warnings: dict[str, str] = {}
    for comparison in (diagnosis.current, diagnosis.selected):
        if comparison is None:
            continue
        values = diagnosis.reported_parameters(comparison)
        errors = diagnosis.reported_errors(comparison)
        fitted = {name for name in values if name not in diagnosis.fixed}
        for name, text in check_parameters(values, errors, independent, fitted).items():
            warnings.setdefault(name, text)
    diagnosis.parameter_warnings = warnings
    diagnosis.independent = independent
    diagnosis.parameter_doubts = scale_doubts(diagnosis)
    for name, text in diagnosis.parameter_doubts.items():
        diagnosis.notes.append(f'{name} {text}.')
    if warnings:
        diagnosis.verdict = DOES_NOT_FIT
        diagnosis.missing_effect = None
        diagnosis.facts = replace(diagnosis.facts, prefix=verdict_line(warnings) + '. ' + diagnosis.facts.prefix)
    if prep is not None and prep.reduced:
        diagnosis.notes.insert(0, 'reduced model (no period-average armature current): the thrust comes from Va '
                               'through the motor map; not identifiable from this record: '
                               + '; '.join(f'{k} ({v})' for k, v in NOT_IDENTIFIABLE.items()) + '.')
    if independent is not None:
        diagnosis.notes.append(independent.describe() + '.')
    doubt = misfit_doubt(diagnosis)
    if doubt is not None:
        diagnosis.notes.insert(0, doubt + '.')
    return diagnosis


def scale_doubts(diagnosis) -> dict[str, str]:
    """Doubts on numbers the fit cannot check itself (name -> text, said beside the number and in a note): the
    armature resistance of the motor observer against the rig's stated value and the observer's own consistency
    (:func:`aeropend_core.identify.plausibility.resistance_doubt`), which catches a current in the wrong scale."""
    from aeropend_core.identify.plausibility import current_scale_ratio, resistance_doubt
    prep = diagnosis.prepared
    motor = getattr(prep, 'motor', None)
    if motor is None or 'armature_resistance' in diagnosis.fixed:
        return {}
    value = motor.parameters.get('motor_resistance', float('nan'))
    sigma = motor.standard_errors.get('motor_resistance', float('nan'))
    text = resistance_doubt(value, sigma, current_scale_ratio(motor.parameters))
    return {'armature_resistance': text} if text else {}

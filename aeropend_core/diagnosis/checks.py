"""A diagnosis's parameters checked against physics (:mod:`aeropend_core.identify.plausibility`), and what the
reduced model cannot tell, written into the diagnosis itself (warnings next to the numbers, verdict, notes).
"""
from __future__ import annotations

import numpy as np

#: Verdict of a diagnosis whose identified parameters fail a physical check.
DOES_NOT_FIT = 'model_does_not_fit'


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
    from aeropend_core.identify.plausibility import check_parameters, free_oscillation, verdict_line
    from aeropend_core.signals.reduced import NOT_IDENTIFIABLE
    prep = diagnosis.prepared
    independent = None
    if prep is not None:
        try:
            independent = free_oscillation(prep.time, prep.angle, prep.gate_voltage, prep.step_indices)
        except (ValueError, np.linalg.LinAlgError):
            independent = None
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
    if warnings:
        diagnosis.verdict = DOES_NOT_FIT
        diagnosis.missing_effect = None
        diagnosis.message = verdict_line(warnings) + '. ' + diagnosis.message
    if prep is not None and prep.reduced:
        diagnosis.notes.insert(0, 'reduced model (no period-average armature current): the thrust comes from Va '
                               'through the motor map; not identifiable from this record: '
                               + '; '.join(f'{k} ({v})' for k, v in NOT_IDENTIFIABLE.items()) + '.')
    if independent is not None:
        diagnosis.notes.append(independent.describe() + '.')
    return diagnosis

"""The verdicts a diagnosis can reach: a leaf module (no imports of aeropend).

A :class:`Verdict` is an :class:`enum.StrEnum`: each member is its own string, so ``diagnosis.verdict ==
'effect_found'`` holds, the JSON output writes the same string as before, and a typo in a verdict's name fails at
once instead of comparing unequal for ever. The words of each verdict are made in :mod:`aeropend_core.present`.
"""
from __future__ import annotations

import enum


class Verdict(enum.StrEnum):
    """What a diagnosis concluded (:attr:`aeropend_core.diagnosis.diagnose.Diagnosis.verdict`).

    Examples
    --------
    >>> from aeropend_core import Verdict
    >>> Verdict('effect_found') is Verdict.EFFECT_FOUND, Verdict.EFFECT_FOUND == 'effect_found'
    (True, True)
    >>> import json; json.dumps({'verdict': Verdict.NOTHING_MISSING})
    '{"verdict": "nothing_missing"}'
    """

    #: one catalog effect (or a set) is missing, and the data pin it
    EFFECT_FOUND = 'effect_found'
    #: nothing significant is missing: the model explains the data down to the noise
    NOTHING_MISSING = 'nothing_missing'
    #: two effects (or a term and a set) explain the data equally: the data cannot tell which is missing
    CONFOUNDED = 'confounded'
    #: error beyond the noise remains that no catalog effect explains
    UNEXPLAINED = 'unexplained'
    #: a term outside the catalog explains the error (the discovery stage)
    TERM_DISCOVERED = 'term_discovered'
    #: a nominal parameter drifts over the record
    DRIFT = 'drift'
    #: a fitted parameter fails a physical check: the model does not fit this data
    MODEL_DOES_NOT_FIT = 'model_does_not_fit'


__all__ = ['Verdict']

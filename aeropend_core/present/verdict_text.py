"""The words of the diagnosis's verdict: the sentence that says what is missing, from the typed results.

The diagnosis (:func:`aeropend_core.diagnosis.diagnose.diagnose`) decides the verdict and returns its typed results
(:class:`~aeropend_core.diagnosis.diagnose.VerdictFacts` in ``Diagnosis.facts``); the words are made here only:
:func:`verdict_of` (the message) and :func:`diagnosis_dict` (the ``--json`` form with the message). The diagnosis
imports nothing from :mod:`aeropend_core.present` (tests/test_architecture.py checks that); this module's inputs are
duck-typed, so it imports nothing from the diagnosis either.
"""
from __future__ import annotations

import math
from collections.abc import Sequence

from aeropend_core.model.effects import get_effect
from aeropend_core.present.discovery_text import discovery_sentence, lookalike_clause, motor_sentence


def size_text(found) -> str:
    """'EFFECT (parameter = value +- sigma UNIT; removes N % of the error beyond the noise)' for one selected effect.

    Parameters
    ----------
    found : Found [-]
        An effect of the selected set (:class:`aeropend_core.diagnosis.diagnose.Found`), parameters SI.

    Returns
    -------
    str
        The effect with its parameters +- 1 sigma in SI units and the share of the error it removes.
    """
    entry = get_effect(found.effect)
    units = {p.name: p.unit for p in entry.parameters}
    values = ', '.join(f'{name} = {value:.4g} +- {found.standard_errors.get(name, float("nan")):.2g} {units[name]}'
                       for name, value in found.parameters.items())
    measurable = (f', {found.share_measurable * 100:.0f} % of the part beyond the noise estimate\'s uncertainty'
                  if found.share_measurable > found.share_removed + 0.05 else '')
    return (f'{found.effect} ({values}; removes {found.share_removed * 100:.0f} % of the error beyond the '
            f'noise{measurable})')


def verdict_message(verdict: str, *, found: Sequence, noise_rms: float, excess_current: float, excess_final: float,
                    within_noise: float, structure: Sequence[dict] = (), drift_text: str = '',
                    heldout_only: Sequence = (), heldout_advice: str = '', discovery=None,
                    explained_below: float = math.inf, reduced_rate_hz: float | None = None, motor=None,
                    motor_input_corrected: bool = False, low_rate_hz: float | None = None, remainder=None) -> str:
    """The verdict's message for `verdict` (the diagnosis's decision), numbers in mrad and SI units.

    Parameters
    ----------
    verdict : str [-]
        ``'drift'``, ``'term_discovered'``, ``'unexplained'``, ``'confounded'``, ``'effect_found'`` or
        ``'nothing_missing'``.
    found : sequence of Found [-]
        The selected set of catalog effects, in the order the search added them (confounded ones included).
    noise_rms : float [rad]
        The angle's measurement noise.
    excess_current : float [rad]
        Held-out error beyond the noise of the model as given.
    excess_final : float [rad]
        Held-out error beyond the noise with the selected set.
    within_noise : float [rad]
        An error beyond the noise below this is "within the noise" (the diagnosis's threshold x its reference).
    structure : sequence of dict [-]
        The residual's strongest signatures (``signature``, ``correlation`` [-]), strongest first.
    drift_text : str [-]
        The drift test's sentence (verdict ``'drift'``).
    heldout_only : sequence of Candidate [-]
        Candidates that explain the held-out part without training evidence (verdict ``'unexplained'``).
    heldout_advice : str [-]
        The experiment that shows the first of them.
    discovery : Discovery, optional [-]
        The discovery stage's result; its sentence is appended when it ran.
    explained_below : float [rad]
        A proven term that leaves more than this explains only part of the error.
    reduced_rate_hz : float, optional [Hz]
        The sample rate of a reduced-model record whose own error at that rate is unmeasured (``'unexplained'``).
    motor : MotorDiscovery, optional [-]
        The motor equation's discovery; its sentence is appended when it proved a term.
    motor_input_corrected : bool [-]
        The model was fitted and searched again on the thrust input rebuilt with the motor's proven term.
    low_rate_hz : float, optional [Hz]
        The sample rate of a record below the rig's: a remainder (``'unexplained'``, full model) or a named effect
        is said to be less sure there.
    remainder : Remainder, optional [-]
        What the selected set leaves (:class:`aeropend_core.diagnosis.remainder.Remainder`): its character (the
        correlation time [s], the median frequency [Hz] of its power beyond the noise) is said beside a set named
        beside it.

    Returns
    -------
    str
        The message (what :func:`verdict_of` returns for a diagnosis).
    """
    pinned = [f for f in found if not f.confounded_with]
    unsure = [f for f in found if f.confounded_with]
    sizes = '; '.join(size_text(f) for f in found)
    verb = 'explain' if len(found) > 1 else 'explains'
    noise_text = f'{noise_rms * 1e3:.2f} mrad'
    if verdict == 'drift':
        message = drift_text + (f' The effect search also selected {sizes}; a drifting parameter can mimic effects.'
                                if found else '')
    elif verdict == 'term_discovered':
        message = f'{sizes} {verb} part of the error. ' if found else ''
    elif verdict == 'unexplained' and found:
        explained = 1.0 - (excess_final / excess_current) ** 2 if excess_current > 0 else float('nan')
        # an effect confounded with another catalog effect is not said to hold: one of the two is there
        held = (f'{"; ".join(size_text(f) for f in pinned)}; judged against that remainder modelled as a '
                f'disturbance, {"they hold" if len(pinned) > 1 else "it holds"}' if pinned else '')
        undecided = ' and '.join(f'one of {" or ".join([f.effect, *f.confounded_with])} ({size_text(f)})'
                                 for f in unsure)
        message = (f'present beside a remainder outside the catalog: {held}'
                   + (f'{"; also " if pinned else ""}{undecided}, but this data cannot tell which' if unsure
                      else '') + '. '
                   f'{"Together they explain" if len(found) > 1 else "It explains"} {max(explained, 0.0) * 100:.0f} % '
                   f'of the mean-square error beyond the noise, with {excess_final * 1e3:.2f} mrad beyond the noise '
                   f'({noise_text}) left unexplained, that no catalog effect explains (outside the catalog)'
                   f'{remainder_character(remainder)}. The '
                   f'residual correlates most with {structure[0]["signature"]} '
                   f'(r = {structure[0]["correlation"]:+.2f}); consider writing an effect with that signature '
                   '(aeropend_core.model.effects.register_effect).')
    elif verdict == 'confounded' and unsure:
        parts = [f'one of {", ".join([f.effect] + list(f.confounded_with))}' for f in unsure]
        message = (f'{" and ".join(parts)} is missing, but this data cannot tell which; see notes.'
                   + (f' Also missing, with confidence: {"; ".join(size_text(f) for f in pinned)}. Add them '
                      f'({" ".join("--add " + f.effect for f in pinned)}).' if pinned else ''))
    elif verdict in ('effect_found', 'confounded'):
        # 'confounded' without an unsure catalog effect: a discovered term explains the data as well as the set
        label = 'missing effect' if len(found) == 1 else 'missing effects'
        alike = lookalike_clause(discovery) if verdict == 'confounded' else ''
        them = "it" if len(found) == 1 else "them"
        message = (f'{label}: {sizes}. '
                   + (f'Not with confidence: {alike}, explains the record as well, and this data cannot tell which '
                      f'(below). With {them} ' if alike else f'Add {them} ')
                   + f'({" ".join("--add " + f.effect for f in found)}){"" if alike else ":"} the held-out error '
                   f'beyond the noise falls from {excess_current * 1e3:.2f} to {excess_final * 1e3:.2f} mrad.'
                   + (' Significant, within the noise: small, but the data support it strongly.'
                      if excess_current <= within_noise else ''))
    elif verdict == 'nothing_missing':
        message = (f'nothing significant is missing: the model error beyond the measurement noise is '
                   f'{excess_final * 1e3:.2f} mrad against {noise_text} of noise, and no catalog effect improves '
                   'the fit significantly.')
    elif heldout_only:
        lead = heldout_only[0]
        message = (f'the model misses the held-out data by {excess_final * 1e3:.2f} mrad beyond the noise '
                   f'({noise_text}). {lead.effect} would explain it ({lead.excess_before * 1e3:.2f} '
                   f'-> {lead.excess_after * 1e3:.2f} mrad) but the training part shows no evidence for it '
                   f'(its BIC does not fall), so it is not recommended: the held-out part holds conditions '
                   f'the training part lacks; {heldout_advice}.')
    else:
        message = (f'the model misses the data by {excess_final * 1e3:.2f} mrad beyond the noise '
                   f'({noise_text}), and no catalog effect explains it (outside the catalog). The '
                   f'residual correlates most with: {structure[0]["signature"]} (r = '
                   f'{structure[0]["correlation"]:+.2f}); consider writing an effect with that signature '
                   f'(aeropend_core.model.effects.register_effect).')
    motor_led = (verdict == 'term_discovered' and motor is not None and bool(motor.proven)
                 and not (discovery is not None and discovery.proven))
    if motor_led:       # the motor equation's term is the verdict: the pendulum's own search is not the news
        message = (message + ' ' + motor_sentence(motor, motor_input_corrected)).strip()
    elif discovery is not None:
        message = (message + ' ' + discovery_sentence(discovery, noise_rms, explained_below)).strip()
    if motor is not None and motor.proven and not motor_led:
        message = (message + ' ' + motor_sentence(motor, motor_input_corrected)).strip()
    if verdict == 'unexplained' and reduced_rate_hz is not None:
        message += (f' At {reduced_rate_hz:.4g} Hz the reduced model\'s own error has not been measured: part '
                    'or all of this remainder can be that model\'s limit at this rate, not a missing effect (a record '
                    'at a higher rate, or with the period-average current, decides).')
    if low_rate_hz is not None and verdict == 'unexplained' and reduced_rate_hz is None:
        message += (f' At {low_rate_hz:.4g} Hz part or all of this remainder can be the model\'s own limit at this '
                    'rate, not a missing effect (clean simulated logs at 22.3 Hz, with nothing missing, kept such a '
                    'remainder in 11 of 16); a record at the rig\'s 490 Hz decides.')
    if low_rate_hz is not None and found:
        names = ' + '.join(f.effect for f in found)
        message += (f' At {low_rate_hz:.4g} Hz a named effect is less sure than at the rig\'s 490 Hz, where the '
                    'catalog\'s false alarms were measured (on clean simulated logs at 245 Hz one of nine named '
                    f'coulomb_friction): confirm {names} on a record at 490 Hz, or with the separating experiment.')
    return message


def remainder_character(remainder) -> str:
    """The remainder's character for the verdict: ``'; the remainder is correlated over 0.4 s, half its power
    beyond the noise below 0.8 Hz (slow: ...)'``, or '' when `remainder` (a Remainder or None) has neither number."""
    if remainder is None:
        return ''
    parts = []
    if math.isfinite(remainder.correlation_time):
        parts.append(f'correlated over {remainder.correlation_time:.2g} s')
    if math.isfinite(remainder.median_frequency):
        parts.append(f'half its power beyond the noise below {remainder.median_frequency:.2g} Hz'
                     + (' (slow: a torque or force the model lacks)' if remainder.median_frequency < 2.0 else
                        ' (fast: the sensor or the motor)'))
    return ('; the remainder is ' + ', '.join(parts)) if parts else ''


def verdict_of(diagnosis) -> str:
    """The verdict's message of a diagnosis (what ``aeropend diagnose`` prints after "Verdict:").

    Parameters
    ----------
    diagnosis : Diagnosis [-]
        A finished diagnosis (:class:`aeropend_core.diagnosis.diagnose.Diagnosis`): its ``facts`` are worded.

    Returns
    -------
    str
        The message, numbers in mrad and SI units; a failed physical check's line first.
    """
    facts = diagnosis.facts
    return facts.prefix + verdict_message(
        facts.verdict, found=facts.found, noise_rms=facts.noise_rms, excess_current=facts.excess_current,
        excess_final=facts.excess_final, within_noise=facts.within_noise, structure=facts.structure,
        drift_text=facts.drift_text, heldout_only=facts.heldout_only, heldout_advice=facts.heldout_advice,
        discovery=facts.discovery, explained_below=facts.explained_below, reduced_rate_hz=facts.reduced_rate_hz,
        motor=facts.motor, motor_input_corrected=facts.motor_input_corrected,
        low_rate_hz=facts.low_rate_hz, remainder=getattr(diagnosis, 'remainder', None))


def diagnosis_dict(diagnosis) -> dict:
    """The ``aeropend diagnose --json`` form: the diagnosis's numbers with the verdict's ``plain`` sentence and its
    ``message`` (the evidence) after ``verdict``.

    Parameters
    ----------
    diagnosis : Diagnosis [-]
        A finished diagnosis.

    Returns
    -------
    dict
        ``diagnosis.numbers_dict()`` with ``plain`` (:func:`~aeropend_core.present.plain_verdict.plain_verdict`) and
        ``message`` (:func:`verdict_of`) inserted after ``verdict``.
    """
    from aeropend_core.present.plain_verdict import plain_verdict
    out = {}
    for key, value in diagnosis.numbers_dict().items():
        out[key] = value
        if key == 'verdict':
            out['plain'] = plain_verdict(diagnosis)
            out['message'] = verdict_of(diagnosis)
    return out


def diagnosis_summary(diagnosis) -> dict:
    """A diagnosis on one screen (:meth:`~aeropend_core.diagnosis.diagnose.Diagnosis.summary`).

    Parameters
    ----------
    diagnosis : Diagnosis [-]
        A finished diagnosis.

    Returns
    -------
    dict
        ``verdict``, ``plain``, ``model``, ``fit_percent`` [%], ``rms_error_rad``, ``noise_rms_rad``,
        ``error_beyond_noise_rad`` [rad], ``missing_effects``, ``add``, the reported ``parameters`` with their
        ``standard_errors`` (SI, 1 sigma; NaN where not estimated) and their doubts: ``parameters_doubt`` (the
        model misses the data: every parameter biased), ``parameter_warnings`` (failed physical checks) and
        ``parameter_doubts``. The full record is :meth:`~aeropend_core.diagnosis.diagnose.Diagnosis.to_dict`.
    """
    from aeropend_core.diagnosis.checks import misfit_doubt
    from aeropend_core.present.plain_verdict import plain_verdict
    current = diagnosis.current
    return {'verdict': str(diagnosis.verdict), 'plain': plain_verdict(diagnosis),
            'model': ' + '.join(('nominal', *diagnosis.effects)),
            'fit_percent': current.fit_percent, 'rms_error_rad': current.rms_error,
            'noise_rms_rad': current.noise_rms, 'error_beyond_noise_rad': current.evaluation.excess_error,
            'missing_effects': diagnosis.missing_effects, 'add': [f.effect for f in diagnosis.found
                                                                  if not f.confounded_with],
            'parameters': diagnosis.reported_parameters(current),
            'standard_errors': diagnosis.reported_errors(current), 'parameters_doubt': misfit_doubt(diagnosis),
            'parameter_warnings': diagnosis.parameter_warnings, 'parameter_doubts': diagnosis.parameter_doubts}


__all__ = ['size_text', 'verdict_message', 'verdict_of', 'diagnosis_dict', 'diagnosis_summary']

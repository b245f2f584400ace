"""One data-quality gate for every recording that is about to be fitted (identify, diagnose, the online windows).

:func:`check_recording` looks at a :class:`~aeropend_core.io.recording.Recording` the way a careful person would
before trusting a number computed from it, and returns a :class:`QualityReport`: the data with every unambiguous
defect repaired, and one :class:`Finding` per defect, each saying what is wrong, where (time range [s], sample
index) and what to do. A defect that no repair can make trustworthy is *refused*: :class:`DataQualityError` (an
:class:`~aeropend_core.errors.AeropendError`, exit status 2 in the CLI) with the finding's message.

The checks use robust statistics (medians, median absolute deviations) and the rig's physics (a pendulum driven by
a small DC motor sampled at 490 Hz), never the values of one particular bad file:

==========================  ===========  ===================================================================
code                        severity     when
==========================  ===========  ===================================================================
``byte_order_mark``         repaired     the CSV starts with a UTF-8 byte-order mark (Excel); it is skipped
``duplicate_column``        refused      two columns share a name (which one is right cannot be told)
``duplicate_sample``        repaired     a sample repeated exactly (same stamp, same values); dropped
``non_finite``              repaired /   NaN/inf samples: a few short runs are interpolated; more are refused
                            refused
``absurd_value``            repaired /   values beyond any unit mistake (abs > 1e6: 1e300, 1e308): as NaN
                            refused
``time_in_milliseconds``    repaired     the stamps step 1e3 x the declared sample time: converted to s
``time_in_microseconds``    repaired     ... 1e6 x (``time_in_nanoseconds``: 1e9 x)
``time_precision``          repaired /   stamps rounded (or jittered) by more than 1 % of the step: replaced by
                            refused      the uniform grid they fit, or refused when no grid fits them
``host_stamps``             repaired /   host stamps with buffering (bursts after stalls): time regularised
                            refused      from the sample order at the declared (or evident) rate, with the
                                         fit's residual; refused when they contradict a constant rate
``sample_rate_mismatch``    refused      stamps (or stamps per sequence count) disagree with the declared rate
``lost_samples``            warning      gaps in the stamps / sequence numbers (not filled here)
``angle_in_degrees``        repaired     the angle spans more than a turn and moves faster than the rod can in
                                         radians, but plausibly in degrees: converted
``angle_range``             warning      the angle spans more than a turn at a plausible rate (over the top, or
                                         slow degrees): said, not changed
``angle_wrapped``           repaired     the angle jumps by one turn at the ends of a 2 pi interval: unwrapped
``angle_jump``              repaired /   a one-turn jump inside the range (encoder glitch): unwrapped; any
                            refused      other jump faster than the rod can move is refused
``current_in_milliamps``    repaired     the current is beyond a small DC motor's amperes but plausible in mA
``voltage_in_millivolts``   repaired     the same for the armature voltage
``duty_in_percent``         repaired     the duty column holds 0..100 instead of 0..1
``outlier``                 repaired /   isolated samples far from their neighbours (Hampel filter on the
                            refused      deviation from a 7-sample running median): interpolated
``voltage_sign``            repaired     Va negative throughout (a PWM drive gives Va >= 0): negated
``current_sign``            repaired     the current is negative throughout and falls as Va rises: negated
``current_inconsistent``    warning      the current is positive but falls as Va rises, or does not jump with
                                         Va at the steps: not the period-average current (read inside the PWM
                                         pulse?); dropped, the reduced model is used (a window: said only)
``current_clipped``         warning      the current holds its lowest value without noise in runs starting where
                                         Va falls (after most falls, or after every fall to 0: a braking current
                                         a one-sided sensor cannot read): dropped, the reduced model is used (a
                                         window: said only)
``voltage_from_duty``       warning      no armature voltage column: Va from the duty by eq (8)
``angle_sign``              repaired     the angle falls as the thrust rises: negated (a node window: warning)
``column_names``            repaired     CSV header spellings and units (``Angle [deg]``): read as SI, said
``unknown_unit``            refused      a unit in the header that is not known for its column
``time_backwards``          refused      stamps going back (samples out of order)
``time_not_increasing``     refused      two different samples with one stamp
``angle_in_milliradians``   repaired     many turns in rad and deg, a plausible range in mrad: converted
``angle_in_counts``         refused      whole numbers beyond a turn: encoder counts (scale unknown)
``angle_zero``              warning      the rod at rest with no thrust reads more than 20 deg from 0
``held_samples``            warning      a signal changes only every L samples (a slower sensor)
``stuck_sensor``            refused      a signal frozen at one value while the input steps
``rod_held``                warning      the angle frozen so, but entered from rest and left without a jump
                                         by a quantised encoder, the current live: a rod held still
``noisy_signal``            warning /    PSNR of the angle or current below 17 dB (warning) or 12 dB (refused)
                            refused
==========================  ===========  ===================================================================

Every check that repairs also says so (severity ``repaired``): nothing is changed silently.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from aeropend_core.errors import AeropendError
from aeropend_core.signals.quality_base import (
    ABSURD,
    DataQualityError,
    Finding,
    MEASURED,
    QualityReport,
    SEVERITIES,
    _Gate,
    findings_to_json,
    quality_lines,
)
from aeropend_core.signals.quality_checks import (
    _check_angle_jumps,
    _check_angle_turns,
    _derive_voltage,
    _check_finite,
    _check_held,
    _check_noise,
    _check_outliers,
    _check_rest_angle,
    _check_current_floor,
    _check_signs,
    _check_stuck,
    _check_time,
    _check_units,
)


# ---------------------------------------------------------------------------------------------------- the gate
def check_recording(recording, *, sample_time: float | None = None, context: str = 'file') -> QualityReport:
    """Check a recording before fitting it; repair what is unambiguous, refuse what is not.

    Parameters
    ----------
    recording : Recording
        Time [s] and signals (``angle`` rad, ``armature_voltage`` V, ``armature_current`` A, ``duty`` 1, optional
        ``sequence`` counts). Its ``findings`` (e.g. from the CSV reader) are carried over.
    sample_time : float, optional
        The declared acquisition period [s] (the rig: 1/490 s). Given, a record at another rate is refused and
        one stamped in milliseconds is converted; None checks the stamps against themselves only.
    context : str
        ``'file'`` (identify, diagnose) or ``'window'`` (the online identification): only the advice differs.

    Returns
    -------
    QualityReport
        ``recording`` (repaired; its ``findings`` hold every finding) and ``findings``.

    Raises
    ------
    DataQualityError
        A refused finding (its message names the problem, where, and what to do).
    """
    source = recording.source or ('the window' if context == 'window' else 'the recording')
    previous = tuple(getattr(recording, 'findings', ()))
    gate = _Gate(recording.time, recording.signals, source, context, previous)
    if gate.time.size:
        _check_time(gate, sample_time)
    measured = [name for name in MEASURED if name in gate.signals]
    for name in measured:
        _check_finite(gate, name)
    _check_units(gate)
    _derive_voltage(gate)
    if 'angle' in gate.signals:
        _check_angle_turns(gate)
    for name in ('angle', 'armature_voltage', 'armature_current'):
        if name in gate.signals:
            _check_outliers(gate, name)
    if gate.time.size > 2:              # a frozen sensor first: its thaw is a jump that it explains
        period = float(np.median(np.diff(gate.time)))
        _check_stuck(gate, 'angle', 'armature_voltage', period)
        _check_stuck(gate, 'armature_current', 'armature_voltage', period)
        _check_stuck(gate, 'armature_voltage', 'duty', period)
    if 'angle' in gate.signals:
        _check_angle_jumps(gate)
    _check_signs(gate)
    _check_current_floor(gate)
    for name in ('angle', 'armature_current'):
        if name in gate.signals:
            _check_noise(gate, name)
            _check_held(gate, name)
    if gate.time.size > 2:
        _check_rest_angle(gate, float(np.median(np.diff(gate.time))))
    findings = gate.findings
    # the recording's own class, so the gate needs nothing from io/ (which calls it when it loads a file)
    repaired = dataclasses.replace(recording, time=gate.time, signals=gate.signals, findings=tuple(findings))
    return QualityReport(repaired, [f for f in findings if f not in previous])


def require_finite(names: Sequence[str], arrays: Sequence[np.ndarray], label: str = '') -> None:
    """Refuse (``non_finite``) arrays holding NaN/inf or of another shape than the first; for callers that take
    plain arrays (identify_pendulum) and so have already passed the gate or never will."""
    from aeropend_core.errors import InsufficientDataError
    for name, x in zip(names, arrays):
        if x.shape != arrays[0].shape:
            raise AeropendError(f'{label}{name} has shape {x.shape}, time has {arrays[0].shape}')
        with np.errstate(invalid='ignore'):
            bad = ~np.isfinite(x) | ((np.abs(x) > ABSURD) if name not in ('time', 't') else False)
        if bad.any():
            raise InsufficientDataError(
                f'{label}{name} has {int(bad.sum())} NaN/inf or absurd (|x| > {ABSURD:g}) value(s), first at sample '
                f'{int(np.argmax(bad))}; pass the data through aeropend_core.signals.quality.check_recording, or '
                'remove or interpolate them')


__all__ = ['Finding', 'QualityReport', 'DataQualityError', 'check_recording', 'findings_to_json', 'require_finite',
           'quality_lines',
           'SEVERITIES']

"""The data-quality gate's checks, one function each, in the order the gate runs them (see
:mod:`aeropend_core.signals.quality` for the table of findings).
"""
from __future__ import annotations

import math

import numpy as np

from aeropend_core.signals.quality_base import (
    ABSURD,
    HAMPEL_SIGMAS,
    HAMPEL_WIDTH,
    MAX_ANGLE_STEP,
    MAX_ANGULAR_RATE,
    MAX_CURRENT,
    MAX_REPAIRED_FRACTION,
    MAX_REPAIRED_RUN,
    MAX_VOLTAGE,
    MIN_PSNR_DB,
    PRECISION_FRACTION,
    RATE_TOLERANCE,
    REST_ANGLE_LIMIT,
    ROD_HELD_COUNTS,
    ROD_HELD_WINDOW,
    STUCK_RESPONSE,
    STUCK_SECONDS,
    WARN_PSNR_DB,
    _Gate,
    _interpolate,
    _quantum,
    _robust_extent,
    _robust_sigma,
    _running_median,
    _runs,
    _typical_rate,
)


#: Lowest sample rate the analysis takes [Hz] (a little below the 20 Hz it is built for: 22 PWM periods of 490 Hz
#: are 22.3 Hz, and a logger's clock may run slow).
LOWEST_RATE = 19.5


# ------------------------------------------------------------------------------------------------------- checks
def _check_time(gate: _Gate, sample_time: float | None) -> None:
    time = gate.time
    bad = np.flatnonzero(~np.isfinite(time))
    if bad.size:
        gate.add('non_finite', 'refused', f'{bad.size} time stamp(s) are not finite numbers (first at sample '
                 f'{bad[0]}); fix or remove those samples', count=bad.size)
    if time.size < 2:
        return
    if _check_host_stamps(gate, sample_time):
        time = gate.time
    step = np.diff(time)
    # Exact repeats (a message recorded twice) are dropped; the precision check below looks at the rest.
    repeated = np.flatnonzero(step == 0) + 1
    if repeated.size:
        same = np.ones(repeated.size, dtype=bool)
        for values in gate.signals.values():
            a, b = values[repeated], values[repeated - 1]
            same &= (a == b) | (np.isnan(a) & np.isnan(b))
        if same.any():
            drop = repeated[same]
            keep = np.ones(time.size, dtype=bool)
            keep[drop] = False
            gate.add('duplicate_sample', 'repaired', f'dropped {drop.size} duplicated sample(s) (same time stamp and '
                     f'values as the one before; first at sample {drop[0]})', gate.span(drop[0], drop[-1]),
                     drop.size)
            gate.time, time = time[keep], time[keep]
            gate.signals = {k: v[keep] for k, v in gate.signals.items()}
            step = np.diff(time)
    backwards = np.flatnonzero(step < 0) + 1
    if backwards.size:
        k = int(backwards[0])
        gate.add('time_backwards', 'refused', f'time stamps go backwards at sample {k} (t = {time[k - 1]:.6f} s then '
                 f'{time[k]:.6f} s; {backwards.size} place(s) in all); the samples are out of order: sort them by time '
                 'or split the record there', gate.span(k - 1, k), backwards.size)
    _check_precision(gate, sample_time)
    time = gate.time
    step = np.diff(time)
    zero = np.flatnonzero(step == 0) + 1
    if zero.size:
        k = int(zero[0])
        gate.add('time_not_increasing', 'refused', f'samples {k - 1} and {k} have the same time stamp t = '
                 f'{time[k]:.6f} s but different values; which one is right cannot be told: fix the time stamps',
                 gate.span(k - 1, k), zero.size)
    typical = float(np.median(step))
    for factor, unit in ((1e-3, 'milliseconds'), (1e-6, 'microseconds'), (1e-9, 'nanoseconds')):
        if sample_time is not None and abs(typical * factor / sample_time - 1.0) < 5 * RATE_TOLERANCE:
            gate.time = time = time * factor
            gate.add(f'time_in_{unit}', 'repaired', f'the t column steps {typical:.6g} per sample, {1 / factor:.0e} x '
                     f'the {sample_time * 1e3:.4g} ms sample time: it is in {unit}; converted to seconds (write t '
                     'in seconds)', gate.span(0, time.size - 1), time.size)
            step, typical = np.diff(time), typical * factor
            break
    if typical > 1.0 / LOWEST_RATE:
        from aeropend_core.signals.rate_accuracy import RATE_ACCURACY
        slowest, errors, _ = RATE_ACCURACY[-1]
        gate.add('sample_rate_mismatch', 'refused', f'samples are {typical:g} time units apart; the t column must be '
                 f'in seconds (the rig samples every 1/490 s = 0.00204 s; divide milliseconds by 1000), and the '
                 f'analysis needs at least {LOWEST_RATE:g} samples per second (a pendulum near 2 Hz): already at '
                 f'{slowest:g} Hz the fitted parameters were off by up to {errors["gravity_stiffness"] * 100:.0f} % '
                 f'(gravity_stiffness), {errors["damping"] * 100:.0f} % (damping) and '
                 f'{errors["thrust_gain"] * 100:.0f} % (thrust_gain) on seeded simulations; record faster',
                 gate.span(0, time.size - 1), time.size)
    if sample_time is not None and abs(typical / sample_time - 1.0) > RATE_TOLERANCE:
        gate.add('sample_rate_mismatch', 'refused', f'samples are {typical * 1e3:.4g} ms apart ({1 / typical:.4g} Hz) '
                 f'but the acquisition rate is {1 / sample_time:.4g} Hz: a decimated or resampled record breaks the '
                 f'held-input and current-kick model; {gate.rate_hint}', gate.span(0, time.size - 1), time.size)
    _check_sequence(gate, sample_time or typical)
    _check_gaps(gate, typical)


def _check_host_stamps(gate: _Gate, sample_time: float | None) -> bool:
    """Stamps of a host that buffers the lines (bursts 0 ms apart after stalls): the time is regularised from the
    sample order (:mod:`aeropend_core.signals.host_clock`) at the declared rate, or at the rate the stamps show when
    none is declared; refused with the cause when they contradict a constant rate. True when regularised."""
    from aeropend_core.signals.host_clock import ClockContradiction, looks_host_buffered, regularise, resolution_of
    time = gate.time
    if not looks_host_buffered(time):
        return False
    n = time.size
    try:
        clock = regularise(time, None if sample_time is None else 1.0 / sample_time, resolution_of(time))
    except ClockContradiction as error:
        hint = ('; if the device logs at another rate, give it (--sample-rate HZ, or a log profile)'
                if sample_time is not None else '')
        gate.add('host_stamps', 'refused', f'the time stamps look like a host\'s (bursts of lines stamped together '
                 f'after stalls) but {error}{hint}', gate.span(0, n - 1), n)
        return False
    gate.time = clock.time - clock.time[0] + time[0]
    gate.add('host_stamps', 'repaired', f'the time stamps are a host\'s, delayed by its buffering (bursts after '
             f'stalls), not the sample times: {clock.describe()}', gate.span(0, n - 1), n)
    return True


def _check_precision(gate: _Gate, sample_time: float | None) -> None:
    """Stamps rounded (``%.9g`` of a large t, epoch seconds in a spreadsheet) or jittered: a uniform grid if one
    fits them within their resolution, else refused."""
    time = gate.time
    n = time.size
    if n < 3:
        return
    step = np.diff(time)
    mean_step = float((time[-1] - time[0]) / (n - 1))
    if mean_step <= 0:
        return
    positive = step[step > 0]
    typical = float(np.median(positive)) if positive.size else mean_step
    quantum = _quantum(step[step < 1.6 * typical], float(np.max(np.abs(time))))     # gaps are not resolution
    regular = step[(step > 0.4 * typical) & (step < 1.6 * typical)]
    jitter = float(np.max(np.abs(regular - typical))) if regular.size else 0.0
    if quantum <= PRECISION_FRACTION * mean_step and jitter <= 0.1 * typical:
        return
    within = step[step < 1.6 * typical]
    if np.mean(np.abs(within - typical) > PRECISION_FRACTION * typical) < 0.005:
        return        # a few odd steps are glitches (refused or reported below), not the resolution of the stamps
    index = np.arange(n, dtype=float)
    slope, offset = np.polyfit(index, time - time[0], 1)
    grid = time[0] + offset + slope * index
    deviation = float(np.max(np.abs(time - grid)))
    resolution = max(quantum, jitter)
    if deviation <= resolution + 0.25 * slope and slope > 0:
        gate.time = grid
        gate.add('time_precision', 'repaired', f'time stamps are rounded or jittered by up to {resolution:.3g} s '
                 f'({100 * resolution / slope:.0f} % of the {slope * 1e3:.4g} ms step), too coarse to give the rate '
                 f'sample by sample; replaced by the uniform grid they fit ({1 / slope:.6g} Hz, largest correction '
                 f'{deviation:.3g} s); write time with more digits', gate.span(0, n - 1), n)
        return
    gate.add('time_precision', 'refused', f'time stamps are rounded or jittered by up to {resolution:.3g} s '
             f'({100 * resolution / typical:.0f} % of the {typical * 1e3:.4g} ms step) and no uniform grid fits '
             'them (lost samples too?): the rate cannot be trusted; write time with more digits (1 us)',
             gate.span(0, n - 1), n)


def _check_sequence(gate: _Gate, sample_time: float) -> None:
    """Stamps against sample counters: per counted sample the stamps must advance by the sample time."""
    sequence = gate.signals.get('sequence')
    if sequence is None or gate.time.size < 3 or not np.all(np.isfinite(sequence)):
        return
    counted = np.diff(sequence)
    advancing = counted > 0
    if not advancing.any():
        return
    per_count = float(np.median(np.diff(gate.time)[advancing] / counted[advancing]))
    if abs(per_count / sample_time - 1.0) > RATE_TOLERANCE:
        gate.add('sample_rate_mismatch', 'refused', f'the stamps advance {per_count * 1e3:.4g} ms per sequence count '
                 f'({1 / per_count:.4g} Hz) but the acquisition rate is {1 / sample_time:.4g} Hz: the source does '
                 f'not sample at the rate assumed; {gate.rate_hint}',
                 gate.span(0, gate.time.size - 1), gate.time.size)


def _check_gaps(gate: _Gate, typical: float) -> None:
    step = np.diff(gate.time)
    gaps = np.flatnonzero(step > 1.5 * typical)
    sequence = gate.signals.get('sequence')
    if sequence is not None and np.all(np.isfinite(sequence)):
        gaps = np.union1d(gaps, np.flatnonzero(np.diff(sequence) > 1))
    if not gaps.size:
        return
    lost = np.maximum(np.round(step[gaps] / typical).astype(int) - 1, 1)
    if sequence is not None and np.all(np.isfinite(sequence)):
        lost = np.maximum(lost, np.diff(sequence)[gaps].astype(int) - 1)
    longest = int(np.argmax(lost))
    k = int(gaps[longest])
    gate.add('lost_samples', 'warning', f'{int(lost.sum())} sample(s) lost in {gaps.size} gap(s), the longest '
             f'{lost[longest] * typical:.3g} s ({lost[longest]} samples) after sample {k} (t = {gate.t(k):.4f}-'
             f'{gate.t(k + 1):.4f} s); they are not filled: the fits are split at the gaps',
             (gate.t(int(gaps[0])), gate.t(int(gaps[-1]) + 1)), int(lost.sum()))


def _check_finite(gate: _Gate, name: str) -> None:
    values = gate.signals[name]
    with np.errstate(invalid='ignore'):
        absurd = np.isfinite(values) & (np.abs(values) > ABSURD)
    missing = ~np.isfinite(values)
    bad = absurd | missing
    if not bad.any():
        return
    runs = _runs(bad)
    longest = max(b - a + 1 for a, b in runs)
    first, last = int(np.flatnonzero(bad)[0]), int(np.flatnonzero(bad)[-1])
    if bad.sum() > MAX_REPAIRED_FRACTION * values.size or longest > MAX_REPAIRED_RUN or bad.all():
        what = f'{int(missing.sum())} NaN/inf and {int(absurd.sum())} absurd (|x| > {ABSURD:g})'
        gate.add('absurd_value' if absurd.sum() > missing.sum() else 'non_finite', 'refused',
                 f'{what} value(s) in {name!r} (first at {gate.at(first)}, longest run {longest} samples): too many to '
                 'interpolate; remove or fix them, or split the record into clean segments', gate.span(first, last),
                 int(bad.sum()))
    gate.signals[name] = _interpolate(values, bad)
    for code, kind in (('non_finite', missing), ('absurd_value', absurd)):
        if not kind.any():
            continue
        where = np.flatnonzero(kind)
        what = 'NaN/inf' if code == 'non_finite' else f'absurd (|x| > {ABSURD:g}, e.g. {values[where[0]]:.3g})'
        gate.add(code, 'repaired', f'{where.size} {what} value(s) in {name!r} (first at {gate.at(int(where[0]))}; '
                 f'runs of at most {longest} samples) replaced by linear interpolation of their neighbours',
                 gate.span(int(where[0]), int(where[-1])), where.size)


def _check_units(gate: _Gate) -> None:
    """Unit mistakes a factor away from the rig's physics: degrees, mA, mV, percent."""
    signals = gate.signals
    n = gate.time.size
    whole = gate.span(0, n - 1)
    if 'angle' in signals:
        extent = _robust_extent(_unwrap_turns(signals['angle'])[0])
        finite = signals['angle'][np.isfinite(signals['angle'])]
        if extent > 2 * math.pi * 1.05 and np.unique(finite).size > 2 and np.all(finite == np.round(finite)):
            gate.add('angle_in_counts', 'refused', f"'angle' holds whole numbers up to {extent:.0f}: encoder counts "
                     '(or whole degrees); which scale cannot be told from the data: convert it to rad '
                     '(2 pi / counts per turn)', whole, n)
        if extent > 2 * math.pi * 1.05:
            extent = _robust_extent(_unwrap_turns(signals['angle'], 360.0)[0])     # as if in degrees
            rate = _typical_rate(signals['angle'], float(np.median(np.diff(gate.time))) if n > 1 else 1.0)
            if math.radians(extent) <= 2 * math.pi * 1.05 and rate > MAX_ANGULAR_RATE:
                signals['angle'] = np.radians(signals['angle'])
                gate.add('angle_in_degrees', 'repaired', f"'angle' reaches {extent:.4g} and moves at {rate:.3g} per s "
                         f'(99th percentile): more than a turn and faster than the rod in radians, '
                         f'{math.radians(extent):.3g} rad and {math.radians(rate):.3g} rad/s in degrees: it is in '
                         'degrees; converted to radians (write the angle in rad)', whole, n)
            elif math.radians(extent) <= 2 * math.pi * 1.05:
                gate.add('angle_range', 'warning', f"'angle' spans {extent:.4g} rad ({extent / (2 * math.pi):.2g} "
                         f'turns) at a plausible rate ({rate:.3g} rad/s): either the rod went over the top, or the '
                         f'angle is in degrees ({math.radians(extent):.3g} rad); if degrees, convert it to rad',
                         whole, n)
            elif extent / 1000.0 <= 2 * math.pi * 1.05 and math.radians(rate) > MAX_ANGULAR_RATE:
                # too fast for degrees of a spinning rod, plausible in mrad
                signals['angle'] = signals['angle'] * 1e-3
                gate.add('angle_in_milliradians', 'repaired', f"'angle' reaches {extent:.4g}: many turns in rad or "
                         f'deg, {extent / 1000:.3g} rad in mrad: it is in milliradians; converted to rad', whole, n)
            else:
                gate.add('absurd_value', 'refused', f"'angle' reaches {extent:.4g} (rad, deg or mrad: many turns), "
                         'not a pendulum angle; write the angle in rad', whole, n)
    for name, limit, unit, code in (('armature_current', MAX_CURRENT, 'A', 'current_in_milliamps'),
                                    ('armature_voltage', MAX_VOLTAGE, 'V', 'voltage_in_millivolts')):
        if name not in signals:
            continue
        extent = _robust_extent(signals[name])
        if extent > limit:
            if extent / 1000.0 <= limit:
                signals[name] = signals[name] * 1e-3
                gate.add(code, 'repaired', f'{name!r} reaches {extent:.4g}, beyond the {limit:g} {unit} a small DC '
                         f'motor allows, and {extent / 1000:.3g} {unit} if in milli{unit}: converted to {unit} (write '
                         f'it in {unit})', whole, n)
            else:
                gate.add('absurd_value', 'refused', f'{name!r} reaches {extent:.4g}, beyond what the rig can give in '
                         f'{unit} or m{unit}; check the column', whole, n)
    if 'duty' in signals:
        extent = _robust_extent(signals['duty'])
        if 1.05 < extent <= 105.0:
            signals['duty'] = signals['duty'] * 0.01
            gate.add('duty_in_percent', 'repaired', f"'duty' reaches {extent:.4g}: it is in percent; converted to a "
                     'fraction 0..1', whole, n)


def _unwrap_turns(angle: np.ndarray, turn: float = 2 * math.pi) -> tuple[np.ndarray, np.ndarray]:
    """(angle with one-turn jumps between samples removed and its median brought within half a turn of 0,
    indices k of the jumps between k and k + 1). `turn` is 2 pi (rad) or 360 (deg)."""
    scale = turn / (2 * math.pi)
    if angle.size < 3:
        return angle, np.zeros(0, dtype=int)
    step = np.diff(angle)
    with np.errstate(invalid='ignore'):
        wraps = np.flatnonzero((np.abs(step) > 0.5 * turn) & (np.abs(np.abs(step) - turn) < 1.0 * scale))
    if not wraps.size or _robust_sigma(step) > 0.1 * scale:
        return angle, wraps[:0]       # none, or noise so large (> 0.1 rad a sample) that a turn is ambiguous
    correction = np.zeros_like(angle)
    correction[wraps + 1] = -turn * np.sign(step[wraps])
    unwrapped = angle + np.cumsum(correction)
    return unwrapped - turn * round(float(np.median(unwrapped)) / turn), wraps


def _check_angle_turns(gate: _Gate) -> None:
    """One-turn jumps: the encoder wrapped (angle kept in [0, 2 pi) or (-pi, pi]) or glitched by a turn."""
    angle = gate.signals['angle']
    unwrapped, wraps = _unwrap_turns(angle)
    if not wraps.size:
        return
    turn = 2 * math.pi
    raw_range = float(np.subtract(*np.percentile(angle, [99.9, 0.1])))
    gate.signals['angle'] = unwrapped
    where = gate.span(int(wraps[0]), int(wraps[-1]) + 1)
    if raw_range <= turn + 0.3:
        gate.add('angle_wrapped', 'repaired', f"'angle' is wrapped into a 2 pi interval ({np.min(angle):.3g} to "
                 f'{np.max(angle):.3g} rad, i.e. [0, 2 pi) or [-pi, pi)): {wraps.size} one-turn jump(s), first at '
                 f'{gate.at(int(wraps[0]) + 1)}; '
                 'unwrapped', where, wraps.size)
    else:
        gate.add('angle_jump', 'repaired', f"'angle' jumps by one turn (2 pi) {wraps.size} time(s), first at "
                 f'{gate.at(int(wraps[0]) + 1)} (an encoder glitch or wrap); unwrapped', where, wraps.size)


def _check_outliers(gate: _Gate, name: str) -> None:
    """Hampel filter: samples far from the 7-sample running median (edges of steps are kept by the median)."""
    values = gate.signals[name]
    if values.size < 4 * HAMPEL_WIDTH:
        return
    deviation = values - _running_median(values)
    # MAD alone is 0 on quantised signals whose deviations are mostly exactly 0: a trimmed RMS bounds it below
    trimmed = np.sort(np.abs(deviation))[:int(0.999 * deviation.size)]
    sigma = max(_robust_sigma(deviation), 0.5 * float(np.sqrt(np.mean(trimmed ** 2))))
    spread = float(np.subtract(*np.percentile(values, [99.5, 0.5])))
    floor = max(5.0 * _quantum(values[:20000]), 0.01 * spread, 1e-12)
    threshold = max(HAMPEL_SIGMAS * sigma, floor)
    bad = np.abs(deviation) > threshold
    # A sample within two quantisation steps of the line between its neighbours is no outlier, however far from
    # the running median: at a low rate the bottom of a swing (counts 43, 39, 38, 39, 43) is far from the median
    # of seven samples, yet it changes by one count.
    quantum = _quantum(values[:20000])
    if quantum > 0 and bad.any():
        curvature = np.zeros_like(values)
        curvature[1:-1] = values[1:-1] - 0.5 * (values[:-2] + values[2:])
        bad &= np.abs(curvature) > 2.0 * quantum
    if bad.any():
        # The last sample of a ramp before a step (a clean Va ending a chirp at 1.088 V and stepping to 0) is far
        # from the median of seven, yet on the straight line of the samples before it: a sample that one side's
        # smooth run predicts is the edge of a step, not an isolated glitch.
        bad &= ~_continues_one_side(values, threshold)
    if name == 'armature_current' and bad.any():
        # the current's kick at a step is physics, not a glitch (when it stays within a few times the current's
        # own range: a 50 A spike next to a step is still a glitch)
        bad &= ~(_after_input_steps(gate, values.size) & (np.abs(deviation) <= 3.0 * max(spread, 1e-12)))
    if not bad.any():
        return
    count = int(bad.sum())
    first, last = int(np.flatnonzero(bad)[0]), int(np.flatnonzero(bad)[-1])
    # the worst of the samples flagged, not of all: a kept current kick may lie further off than any glitch
    worst = int(np.flatnonzero(bad)[np.argmax(np.abs(deviation[bad]))])
    if count > MAX_REPAIRED_FRACTION * values.size:
        gate.add('outlier', 'refused', f'{count} samples of {name!r} lie far from their neighbours (more than '
                 f'{threshold:.3g} off the running median; worst {values[worst]:.4g} at {gate.at(worst)}): too many to '
                 'be isolated glitches; check the sensor and its wiring', gate.span(first, last), count)
    gate.signals[name] = _interpolate(values, bad)
    gate.add('outlier', 'repaired', f'{count} isolated outlier(s) in {name!r} (worst {values[worst]:.4g} at '
             f'{gate.at(worst)}, {abs(deviation[worst]) / max(sigma, 1e-300):.3g} robust sigmas off its neighbours) '
             'replaced by linear interpolation', gate.span(first, last), count)


def _continues_one_side(values: np.ndarray, tolerance: float) -> np.ndarray:
    """Mask of the samples that the straight line through the three samples on one side of them predicts within
    `tolerance` (the unit of `values`), where those three are themselves smooth (second difference within
    `tolerance`): a glitch of one or two samples never is, since its own neighbours break the side's line."""
    n = values.size
    left_predicted = np.full(n, np.inf)
    right_predicted = np.full(n, np.inf)
    if n < 7:
        return np.zeros(n, dtype=bool)
    with np.errstate(over='ignore', invalid='ignore'):
        a, b, c = values[:-3], values[1:-2], values[2:-1]          # samples k-3, k-2, k-1 for k = 3 .. n-1
        # least-squares line through offsets -3, -2, -1 evaluated at 0
        left_predicted[3:] = np.where(np.abs(a - 2 * b + c) <= tolerance, (4 * c + b - 2 * a) / 3, np.inf)
        d, e, f = values[1:-2], values[2:-1], values[3:]           # samples k+1, k+2, k+3 for k = 0 .. n-4
        right_predicted[:-3] = np.where(np.abs(d - 2 * e + f) <= tolerance, (4 * d + e - 2 * f) / 3, np.inf)
        return (np.abs(values - left_predicted) <= tolerance) | (np.abs(values - right_predicted) <= tolerance)


#: Time after a step of the input (duty or Va) in which the armature current's kick is physics, not an outlier [s]
#: (at least the first two samples at and after the step: at 25-60 Hz the kick is one or two samples long).
KICK_TIME = 0.02


def _after_input_steps(gate: _Gate, n: int) -> np.ndarray:
    """Mask (n,) of the samples within :data:`KICK_TIME` (at least two samples) of a step of the duty (or of Va
    when there is no duty column), and of the record's start: a step is a change beyond 6 robust sigmas of the
    changes and 2 % of the range."""
    source = gate.signals.get('duty', gate.signals.get('armature_voltage'))
    mask = np.zeros(n, dtype=bool)
    if source is None or source.size != n or n < 3:
        return mask
    change = np.abs(np.diff(np.nan_to_num(source)))
    spread = float(np.subtract(*np.percentile(source[np.isfinite(source)], [99.5, 0.5]))) if np.isfinite(
        source).any() else 0.0
    steps = np.flatnonzero(change > max(6.0 * _robust_sigma(np.diff(np.nan_to_num(source))), 0.02 * spread,
                                        1e-12)) + 1
    period = float(np.median(np.diff(gate.time))) if gate.time.size > 1 else 0.0
    width = max(2, int(math.ceil(KICK_TIME / period))) if period > 0 else 2
    for k in steps:
        mask[k:k + width] = True
    # the record's start counts as a step: a log may start as the motor switches on (at 24.5 Hz the current went
    # 0.04, 1.55, 1.38, 1.26 A, and its 2nd and 3rd samples were "repaired" to 0.44 and 0.85 A, which bent the
    # motor observer's Rm 6 % low), and the running median has no samples before it
    mask[:max(width, HAMPEL_WIDTH // 2 + 1)] = True
    return mask


def _check_noise(gate: _Gate, name: str) -> None:
    """Peak signal-to-noise ratio 20 log10(max|x| / noise RMS): a signal that is mostly noise gives no numbers."""
    from aeropend_core.signals.preprocess import noise_rms
    values = gate.signals[name]
    if values.size < 100:
        return
    noise = noise_rms(values)
    peak = float(np.percentile(np.abs(values), 99.9))
    if not (noise > 0 and peak > 0):
        return
    psnr = 20 * math.log10(peak / noise)
    whole = gate.span(0, values.size - 1)
    if psnr < MIN_PSNR_DB:
        gate.add('noisy_signal', 'refused', f'{name!r} is mostly noise: PSNR {psnr:.1f} dB (noise RMS {noise:.3g}, '
                 f'peak {peak:.3g}); nothing can be identified from it: check the sensor, its wiring and its units',
                 whole, values.size)
    elif psnr < WARN_PSNR_DB:
        gate.add('noisy_signal', 'warning', f'{name!r} is very noisy: PSNR {psnr:.1f} dB (noise RMS {noise:.3g}, '
                 f'peak {peak:.3g}); estimates will be poor and small effects unseen', whole, values.size)


def _check_angle_jumps(gate: _Gate) -> None:
    """Steps of the angle faster than the rod can move, lasting longer than an outlier: refused."""
    angle = gate.signals['angle']
    step = np.diff(angle)
    if step.size < 3:
        return
    threshold = max(MAX_ANGLE_STEP, 12.0 * _robust_sigma(step))
    interval = np.diff(gate.time)
    regular = interval <= 1.5 * float(np.median(interval))     # across a gap the rod may have moved anywhere
    big = np.flatnonzero((np.abs(step) > threshold) & regular)
    if big.size:
        k = int(big[0])
        gate.add('angle_jump', 'refused', f"'angle' jumps by {step[k]:+.3g} rad from {gate.at(k)} to the next sample, "
                 f'faster than the rod can move ({big.size} such jump(s)); the encoder glitched: {gate.cut_hint}',
                 gate.span(k, int(big[-1]) + 1), big.size)


def _check_signs(gate: _Gate) -> None:
    """The rig's sign conventions: Va >= 0 (a PWM drive), the current follows Va, and the thrust lifts the angle.

    An angle whose relation to the thrust is clearly reversed (correlation < -0.5) was logged with the opposite
    sign (a mirrored encoder): negated, and said. A current is negated only on unambiguous evidence: it falls as Va
    rises *and* it is negative at positive duty (a probe the other way round), so that the negated current is positive
    as a unidirectional drive's must be. A current that is positive but falls as Va rises, or does not jump with Va
    at the duty steps, is not the period-average armature current (:func:`_check_current_consistency`)."""
    signals = gate.signals
    n = gate.time.size
    if n < 200 or 'armature_voltage' not in signals:
        return
    whole = gate.span(0, n - 1)
    voltage = signals['armature_voltage']
    magnitude = float(np.percentile(np.abs(voltage), 99))
    if magnitude > 0 and float(np.percentile(voltage, 99)) < 0.05 * magnitude:
        signals['armature_voltage'] = voltage = -voltage
        gate.add('voltage_sign', 'repaired', "'armature_voltage' is negative throughout (the PWM drive gives Va >= 0): "
                 'its sign is reversed; negated', whole, n)
    width = max(int(0.1 / max(float(np.median(np.diff(gate.time))), 1e-9)) | 1, 3)
    thrust = voltage * np.abs(voltage)
    if np.ptp(thrust) <= 0:
        return
    if 'armature_current' in signals and np.ptp(signals['armature_current']) > 0:
        _check_current_consistency(gate, voltage, width)
    if 'angle' in signals and np.ptp(signals['angle']) > 0:
        correlation = float(np.corrcoef(_running_median(signals['angle'], width), thrust)[0, 1])
        if correlation < -0.5:
            text = f"'angle' falls when the thrust (Va^2) rises (correlation {correlation:.2f}): its sign is " \
                   'reversed (mirrored sensor)'
            if gate.context == 'window':          # a few seconds are not enough to change data on: said only
                gate.add('angle_sign', 'warning', text + '; check the sensor\'s sign', whole, n)
            else:
                signals['angle'] = -signals['angle']
                gate.add('angle_sign', 'repaired', text + '; negated', whole, n)


#: The text every inconsistent-current finding carries (what it probably is).
NOT_PERIOD_AVERAGE = 'does not look like the period-average armature current: read inside the PWM pulse?'


def _check_current_consistency(gate: _Gate, voltage: np.ndarray, width: int) -> None:
    """Is the current column the period-average armature current that eq (5) needs?

    With Va >= 0 from a unidirectional drive the armature current is >= 0 and rises with Va (Ia = (Va - e)/Ra, and
    at a duty step e is continuous, so Ia jumps with Va). A current negative at positive duty that falls as Va rises is
    a probe the other way round: negated (the only sign repair). A current that falls as Va rises while positive, or
    that does not jump with Va at the duty steps, is not that current (a one-sided sensor read at a fixed phase
    inside the on-pulse gives (V_supply - e)/R, which falls as the speed rises): negating it would give a negative
    current at positive duty. It is then dropped and the reduced model (:mod:`aeropend_core.signals.reduced`) is
    used; said as a warning (in an online window: said only)."""
    signals = gate.signals
    n = gate.time.size
    whole = gate.span(0, n - 1)
    current = signals['armature_current']
    smooth = _running_median(current, width)
    driven = voltage > 0.05 * float(np.percentile(np.abs(voltage), 99))     # at positive duty (no pulse at 0)
    if np.count_nonzero(driven) < 100 or np.ptp(voltage[driven]) <= 0 or np.ptp(smooth[driven]) <= 0:
        return
    correlation = float(np.corrcoef(smooth[driven], voltage[driven])[0, 1])
    # negative at positive duty (braking currents after a step down may be positive: three quarters suffice)
    negative = float(np.percentile(current[driven], 75)) < 0.0
    if correlation < -0.5 and negative:
        if gate.context == 'window':
            gate.add('current_sign', 'warning', "'armature_current' is negative at positive duty and falls when the "
                     f'armature voltage rises (correlation {correlation:.2f}): its sign looks reversed; check the '
                     'probe', whole, n)
            return
        signals['armature_current'] = current = -current
        gate.add('current_sign', 'repaired', "'armature_current' is negative at positive duty and falls when the "
                 f'armature voltage rises (correlation {correlation:.2f}): a probe the other way round; negated (now '
                 'positive '
                 'and rising with Va, as a unidirectional drive gives)', whole, n)
        correlation, negative = -correlation, False
    reason = ''
    if negative and correlation >= -0.5:
        reason = (f'it is negative at positive duty but does not fall as the armature voltage rises (correlation '
                  f'{correlation:.2f}): neither it nor its negation behaves like the current a unidirectional drive '
                  'gives')
    elif correlation < -0.5:
        reason = (f'it is positive but falls when the armature voltage rises (correlation {correlation:.2f}); '
                  'negated it would be negative at positive duty, which a unidirectional drive cannot give')
    else:
        jumps = _step_jumps(gate, voltage, current)
        if jumps is not None and jumps <= 0:
            reason = ('it does not jump up with the armature voltage at the duty steps (the back-EMF is continuous, '
                      'so the period-average current must)')
    if not reason:
        return
    text = f"'armature_current' {NOT_PERIOD_AVERAGE} {reason}"
    if gate.context == 'window':
        gate.add('current_inconsistent', 'warning', text + '; check the current sensing', whole, n)
        return
    del signals['armature_current']
    gate.add('current_inconsistent', 'warning', text + '. The current is not used: the reduced model (thrust from '
             'Va through the motor\'s static map and lag; no armature resistance) is fitted instead. If the current '
             'is right, fix its column (sign, scale, sampling phase) in the log or its import profile', whole, n)


def _check_current_floor(gate: _Gate) -> None:
    """A current column that cannot go below a floor: a one-sided sense resistor or an ADC that reads 0 for the
    braking current.

    After the armature voltage falls, the back-EMF exceeds Va and the period-average current of a braking drive is
    negative until the motor slows. A sensor that cannot read it holds its lowest value exactly (no noise) in runs that
    start at those falls. The clipped samples would pull the motor observer (and the armature resistance) away from
    the truth, and a corrected value cannot be made up, so the current is not used: the reduced model is fitted
    instead (in an online window: said only). A current whose lowest value is simply its rest (the record starts at
    duty 0) is not this: its runs at the floor do not follow falls of Va."""
    signals = gate.signals
    current, voltage = signals.get('armature_current'), signals.get('armature_voltage')
    n = gate.time.size
    if current is None or voltage is None or n < 200:
        return
    floor = float(np.min(current))
    at_floor = current == floor
    runs = [(a, b) for a, b in _runs(at_floor) if b - a >= 2]               # three or more samples held exactly
    moving = np.diff(current)[~(at_floor[1:] & at_floor[:-1])]
    if not runs or moving.size == 0 or np.mean(moving == 0) > 0.5:          # a coarse or held sensor: not this
        return
    from aeropend_core.signals.preprocess import detect_steps
    sample_time = float(np.median(np.diff(gate.time)))
    span = float(np.subtract(*np.percentile(voltage, [99, 1])))
    falls = [k for k in detect_steps(voltage, sample_time) if 3 <= k <= n - 3
             and float(np.median(voltage[k:k + 3]) - np.median(voltage[k - 3:k])) < -0.1 * span]
    window = max(int(round(0.5 / sample_time)), 2)
    enough = max(10, 0.005 * n)

    def following(steps):          # the floor runs that start within `window` samples after one of `steps`
        return [(a, b) for a, b in runs if any(0 <= a - k <= window for k in steps)]
    after_fall = following(falls)
    held = sum(b - a + 1 for a, b in after_fall)
    # a fall of Va to 0 leaves the motor spinning: a braking drive's current is negative until it stops, so a floor
    # held after every such fall (one is enough) is the clipped braking current, whatever the smaller falls show (at
    # 20-45 Hz the braking after a fall to a lower level lasts one or two samples, too short for a run: clean logs
    # had floor runs after each of their one or two falls to 0 and after none of the others, were not found
    # clipped, and got a false cable_torque). A bidirectional sensor's braking current is negative there, and its
    # noise never holds one value for three samples.
    to_rest = [k for k in falls if float(np.median(voltage[k:k + 3])) <= 0.05 * span]
    held_rest = sum(b - a + 1 for a, b in following(to_rest))
    after_falls = len(after_fall) >= 3 and held >= enough and len(after_fall) >= 0.5 * len(falls)
    after_every_rest = len(to_rest) >= 1 and held_rest >= enough and all(following([k]) for k in to_rest)
    if not (after_falls or after_every_rest):
        return
    if after_falls:
        where = f'in {len(after_fall)} runs that start when the armature voltage falls'
    else:
        held, where = held_rest, (f'in runs after each of the {len(to_rest)} falls of the armature voltage to 0'
                                  if len(to_rest) > 1 else 'in runs after the fall of the armature voltage to 0')
    text = (f"'armature_current' holds its lowest value ({floor:.4g} A) without noise for {held} samples "
            f'({held / n * 100:.1f} %) {where}, where a braking drive\'s current is negative: the sensor cannot read '
            'below that value (a one-sided sense resistor or ADC)')
    if gate.context == 'window':
        gate.add('current_clipped', 'warning', text + '; check the current sensing', gate.span(0, n - 1), held)
        return
    del signals['armature_current']
    gate.add('current_clipped', 'warning', text + '. The clipped current would bias the motor observer and the '
             'armature resistance, so it is not used: the reduced model (thrust from Va through the motor\'s static '
             'map and lag; no armature resistance) is fitted instead. A sensor that reads both signs (or a current '
             'offset that keeps the braking current above the ADC\'s zero) gives the full model', gate.span(0, n - 1),
             held)


def _step_jumps(gate: _Gate, voltage: np.ndarray, current: np.ndarray) -> float | None:
    """Median of sign(dVa) x (jump of the current) across the larger Va steps, relative to the current's spread
    (None: fewer than 5 steps)."""
    from aeropend_core.signals.preprocess import detect_steps
    sample_time = float(np.median(np.diff(gate.time)))
    steps = detect_steps(voltage, sample_time)
    span = float(np.subtract(*np.percentile(voltage, [99, 1])))
    steps = steps[(steps >= 3) & (steps + 3 <= voltage.size)]
    # medians of the 3 (voltage) and 2 (current) samples after and before each step, all steps at once
    d_voltage = np.median(voltage[steps[:, None] + np.arange(3)], axis=1) - \
        np.median(voltage[steps[:, None] + np.arange(-3, 0)], axis=1)
    larger = np.abs(d_voltage) >= 0.1 * span
    steps, d_voltage = steps[larger], d_voltage[larger]
    values = np.sign(d_voltage) * (np.median(current[steps[:, None] + np.arange(2)], axis=1)
                                   - np.median(current[steps[:, None] + np.arange(-2, 0)], axis=1))
    if values.size < 5:
        return None
    return float(np.median(values))


def _derive_voltage(gate: _Gate) -> None:
    """No armature voltage but a duty column: Va from the duty by the paper's eq (8) (said as a warning)."""
    if 'armature_voltage' in gate.signals or 'duty' not in gate.signals:
        return
    from aeropend_core.signals.reduced import voltage_from_duty
    n = gate.time.size
    gate.signals['armature_voltage'] = voltage_from_duty(np.nan_to_num(gate.signals['duty']))
    gate.add('voltage_from_duty', 'warning', "no 'armature_voltage' column: computed from 'duty' by the paper's eq "
             '(8) (Va = k0 + k1 sqrt(k2 duty + k3) with its constants); the thrust gain is relative to that map',
             gate.span(0, max(n - 1, 0)), n)


def _check_rest_angle(gate: _Gate, sample_time: float) -> None:
    """With no thrust the rod hangs: the angle should read 0 there (mod 2 pi). The settled angle of each held input
    level, extrapolated to zero thrust (a line through the lower half of the levels, thrust ~ Va|Va|), estimates
    it; an offset beyond 20 deg (more than the catalog's small sensor-offset effect) breaks sin(angle) in every
    model."""
    from aeropend_core.signals.preprocess import detect_steps
    if 'angle' not in gate.signals or 'armature_voltage' not in gate.signals or gate.time.size < 500 \
            or gate.context == 'window':              # a window's few levels extrapolate too loosely
        return
    voltage, angle = gate.signals['armature_voltage'], gate.signals['angle']
    if np.subtract(*np.percentile(angle, [99.9, 0.1])) > 2 * math.pi:
        return                                          # the rod went over the top: no single resting angle
    bounds = np.concatenate(([0], detect_steps(voltage, sample_time), [voltage.size]))
    levels, settled = [], []
    for first, stop in zip(bounds[:-1], bounds[1:]):
        if (stop - first) * sample_time < 0.5:
            continue
        level = float(np.median(voltage[first:stop]))
        levels.append(level * abs(level))
        settled.append(float(np.median(angle[first + int(0.6 * (stop - first)):stop])))
    if len(levels) < 6:
        return
    levels, settled = np.array(levels), np.array(settled)
    lower = levels <= np.median(levels)
    if lower.sum() < 3 or np.ptp(levels[lower]) <= 0:
        return
    slope, rest = np.polyfit(levels[lower], settled[lower], 1)
    offset = rest - 2 * math.pi * round(rest / (2 * math.pi))
    if abs(offset) > REST_ANGLE_LIMIT:
        gate.add('angle_zero', 'warning', f"with no thrust the rod hangs, but 'angle' extrapolates to {rest:.3g} rad "
                 f'there ({math.degrees(offset):+.0f} deg from 0, from the settled angle of {len(levels)} input '
                 'levels): the angle\'s zero is not the hanging position; subtract the offset (small offsets: '
                 f'--add {_offset_effect()})', gate.span(0, angle.size - 1), angle.size)


def _check_held(gate: _Gate, name: str) -> None:
    """A sensor read slower than the logger: each value repeated L times (e.g. 98 Hz in a 490 Hz log). The data
    are true but coarser than their stamps say: said."""
    values = gate.signals.get(name)
    if values is None or values.size < 500:
        return
    changes = np.flatnonzero(np.diff(values) != 0)
    if changes.size < 20:
        return
    lengths = np.diff(changes)
    common = int(np.bincount(lengths).argmax())
    if common >= 2 and np.mean(lengths == common) > 0.8:
        rate = 1.0 / (common * float(np.median(np.diff(gate.time))))
        gate.add('held_samples', 'warning', f'{name!r} changes only every {common} samples ({rate:.4g} Hz): the sensor '
                 'is read slower than the record is sampled; the fit sees steps that are not the physics',
                 gate.span(0, values.size - 1), values.size)


def _check_stuck(gate: _Gate, name: str, driver: str, sample_time: float) -> None:
    """A signal frozen at one value for STUCK_SECONDS or more while its driver (the input) steps. A frozen angle
    the rod can explain (:func:`_rod_held`: held by dry friction or below the thrust that moves it) is said, not
    refused."""
    if name not in gate.signals or driver not in gate.signals:
        return
    values, drive = gate.signals[name], gate.signals[driver]
    if values.size < 3:
        return
    starts = np.concatenate(([0], np.flatnonzero(np.diff(values) != 0) + 1))
    stops = np.concatenate((starts[1:], [values.size])) - 1            # inclusive
    smooth = _running_median(drive)
    span = float(np.subtract(*np.percentile(smooth, [99, 1])))
    if span <= 0:
        return
    minimum = max(int(STUCK_SECONDS / sample_time), 20)
    response = int(STUCK_RESPONSE / sample_time)
    long_enough = stops - starts + 1 >= minimum + response        # the runs worth a look, found at once
    held = []
    for first, last in zip(starts[long_enough], stops[long_enough]):
        moved = float(np.ptp(smooth[first:last + 1 - response]))   # an input change the sensor had time to see
        if moved <= 0.2 * span:
            continue
        if name == 'angle' and _rod_held(gate, first, last, sample_time):
            held.append((first, last, moved))
            continue
        gate.add('stuck_sensor', 'refused', f'{name!r} is stuck at {values[first]:.6g} for '
                 f'{(last - first) * sample_time:.3g} s ({gate.at(first, last)}) while {driver!r} changes by '
                 f'{moved:.3g}: the sensor froze; {gate.cut_hint}', gate.span(first, last), last - first + 1)
    if held:
        first, last, moved = max(held, key=lambda run: run[1] - run[0])
        gate.add('rod_held', 'warning', f'{name!r} holds one value in {len(held)} span(s) of '
                 f'{STUCK_SECONDS + STUCK_RESPONSE:g} s or more while {driver!r} changes (longest '
                 f'{(last - first) * sample_time:.3g} s, {gate.at(first, last)}, {driver!r} changing by {moved:.3g}), '
                 'but the rod enters each span from rest and leaves it from the same count, and the current '
                 'follows the input: read as a rod held still (dry friction, or a thrust below what moves it), '
                 'not a frozen sensor; if the rod did move there, the sensor froze: cut the record around it',
                 gate.span(first, last), sum(stop - start + 1 for start, stop, _ in held))


def _rod_held(gate: _Gate, first: int, last: int, sample_time: float) -> bool:
    """Whether the angle frozen over samples first..last (inclusive) is a rod at rest rather than a stuck sensor.

    A still rod under a quantised encoder whose noise is below one count reads one value: the reading then enters
    the span from rest and leaves it without a jump (within ROD_HELD_COUNTS counts over ROD_HELD_WINDOW s on each
    side; a record that starts at rest has no side before), while a frozen sensor thaws with a jump to wherever
    the rod went. Required besides: the angle is quantised (its steps are whole multiples of one count), the span
    ends before the record does (a sensor frozen to the end cannot be told from a held rod: refused) and the
    current, where recorded, is not frozen with it."""
    angle = gate.signals['angle']
    window = max(int(round(ROD_HELD_WINDOW / sample_time)), 3)
    if last + window >= angle.size:                    # no thaw to look at
        return False
    steps = np.abs(np.diff(angle))
    steps = steps[steps > 0]
    if steps.size < 20:
        return False
    count = float(np.min(steps))
    ratio = steps / count
    if count <= 0 or np.mean(np.abs(ratio - np.round(ratio)) < 0.01) < 0.99:
        return False                                     # not a quantised reading: a still rod would show noise
    current = gate.signals.get('armature_current')
    if current is not None and np.ptp(current[first:last + 1]) <= 0:
        return False
    value = angle[first]
    sides = np.concatenate((angle[max(first - window, 0):first], angle[last + 1:last + 1 + window]))
    return bool(np.max(np.abs(sides - value)) <= (ROD_HELD_COUNTS + 0.01) * count)


def _offset_effect() -> str:
    """Name of the catalog effect that adds a constant to the measured angle (from its record's kernel term)."""
    from aeropend_core.model.effects import CATALOG
    return next((e.name for e in CATALOG.values() if any(kind == 'measured_offset' for kind, _ in e.kernel_terms)),
                'the sensor-offset effect')

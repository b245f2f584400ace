"""Plausibility checks after the CRC (aeropend_core.rig.link_checks) and the clock checks of SampleClock.

Each case is one that a CRC-passing damaged frame or a wrong clock produced in issue 23: the checker must withhold
what the stream contradicts, keep what it confirms, and the clock must say what is wrong with numbers.
"""
from __future__ import annotations

import numpy as np
import pytest

from aeropend_core.rig import protocol as P
from aeropend_core.rig.link_checks import SEQUENCE_MODULUS, FrameChecker
from aeropend_core.rig.sample_clock import SampleClock


def frames(sequences, counts=(500, 512, 300)):
    return [P.SampleFrame(int(s) % SEQUENCE_MODULUS, *counts, 1000, 0) for s in sequences]


def accepted(checker, sequences):
    return [c.frame.sequence for c in checker.check(frames(sequences))]


def test_a_clean_stream_passes_untouched():
    checker = FrameChecker()
    assert accepted(checker, range(100, 200)) == list(range(100, 200))
    assert checker.counters.implausible_sequence == checker.counters.implausible_range == 0


@pytest.mark.parametrize('offset', [+100000, -3000, +2, -1, -1010, +SEQUENCE_MODULUS // 2])
def test_a_lone_sequence_jump_is_withheld_and_counted(offset):
    """A damaged frame (number + offset) between intact ones: withheld, nothing counted lost, no reset."""
    checker = FrameChecker()
    stream = list(range(1000, 1010)) + [1010 + offset] + list(range(1011, 1020))
    out = checker.check(frames(stream))
    numbers = [c.frame.sequence for c in out]
    assert numbers == sorted(set(numbers))                  # never a second sample with the same number
    assert not any(c.reset for c in out)
    assert sum(c.lost for c in out) == 1                    # only the damaged sample itself is missing
    assert checker.counters.implausible_sequence == 1


def test_a_real_gap_and_a_real_reset_are_confirmed_by_the_stream():
    checker = FrameChecker()
    out = checker.check(frames(list(range(0, 50)) + list(range(2000, 2010)) + list(range(3, 20))))
    gap = next(c for c in out if c.frame.sequence == 2000)
    assert gap.lost == 1950 and not gap.reset
    reset = next(c for c in out if c.reset)
    assert reset.frame.sequence == 3
    assert [c.frame.sequence for c in out][-17:] == list(range(3, 20))
    assert checker.counters.implausible_sequence == 0


def test_a_held_sample_waits_for_the_next_read():
    checker = FrameChecker()
    checker.check(frames(range(10)))
    assert checker.check(frames([500])) == [] and checker.holding
    out = checker.check(frames([501, 502]))
    assert [c.frame.sequence for c in out] == [500, 501, 502] and out[0].lost == 490


def test_the_counter_wrap_is_a_continuation():
    checker = FrameChecker()
    start = SEQUENCE_MODULUS - 5
    out = checker.check(frames(range(start, start + 10)))
    assert [c.frame.sequence for c in out] == list(range(start, start + 10))     # extended past 2^32
    assert not any(c.reset or c.lost for c in out)
    assert checker.counters.wraps == 1


@pytest.mark.parametrize('field', ['current_counts', 'angle_counts', 'voltage_counts'])
def test_impossible_adc_counts_are_withheld(field):
    checker = FrameChecker()
    stream = frames(range(10))
    stream[5] = stream[5]._replace(**{field: 65535})
    out = checker.check(stream)
    assert 5 not in [c.frame.sequence for c in out]
    assert checker.counters.implausible_range == 1
    assert all(c.frame.current_counts <= 1023 and c.frame.angle_counts <= 1023 for c in out)
    good = frames([10])[0]._replace(flags=0x80)
    assert checker.check([good]) == [] and checker.counters.implausible_range == 2


def clock_run(rate_error=0.0, step_at=None, step=0.0, seconds=20.0, seed=1):
    """Stamp a device with the given clock error read in USB-like blocks; the host clock steps by `step` s at
    `step_at` s. Returns (clock, acquisition times, stamps, time the rate fault was first raised or None)."""
    rng = np.random.default_rng(seed)
    period = P.SAMPLE_PERIOD
    n = int(seconds / period)
    sequence = np.arange(n)
    acquisition = 100.0 + sequence * period * (1.0 + rate_error)
    clock = SampleClock(period)
    stamps = np.empty(n)
    start, raised = 0, None
    while start < n:
        stop = min(n, start + int(rng.integers(5, 16)))
        arrival = acquisition[stop - 1] + 0.001 + rng.exponential(0.0015)
        if step_at is not None and acquisition[stop - 1] - 100.0 >= step_at:
            arrival += step
        stamps[start:stop] = clock.stamp_many([int(s) for s in sequence[start:stop]], arrival)
        if clock.rate_fault and raised is None:
            raised = acquisition[stop - 1] - 100.0
        start = stop
    return clock, acquisition, stamps, raised


@pytest.mark.parametrize(('rate_error', 'within'), [(0.015, 6.0), (-0.015, 6.0), (-0.5, 3.0), (1.0, 8.0)])
def test_a_device_clock_outside_tolerance_is_a_fault_with_its_number(rate_error, within):
    """1.5 % slow or fast, twice or half the rate: rate_fault within a few seconds, the measured error right."""
    clock, _, _, raised = clock_run(rate_error)
    assert raised is not None and raised <= within
    assert clock.rate_fault
    assert clock.rate_error == pytest.approx(rate_error, abs=max(1e-3, clock.rate_error_bound))
    assert clock.rate_error_bound >= 0.0     # a ± said next to the number is never negative (was -0.00 % at -0.5)
    assert clock.host_steps == []


@pytest.mark.parametrize('rate_error', [0.0, 0.005, -0.005])
def test_a_device_clock_within_tolerance_is_no_fault(rate_error):
    clock, *_, raised = clock_run(rate_error, seconds=30.0)
    assert raised is None and not clock.rate_fault and clock.rate_verified
    assert clock.host_steps == []


def test_a_device_clock_is_within_its_tolerance_only_once_its_bound_shows_it():
    """rate_within: verified and inside max_drift by more than the bound (the bridge's OK); a fault never is, nor a
    rate not yet verified."""
    exact, *_ = clock_run(0.0, seconds=30.0)
    assert exact.rate_within and abs(exact.rate_error) + exact.rate_error_bound <= exact.max_drift
    slow, *_ = clock_run(0.015)
    assert slow.rate_fault and not slow.rate_within
    assert not SampleClock(P.SAMPLE_PERIOD).rate_within
    # shown in ppm: the measured bound, and a capped figure (not 'inf ppm') before any measurement
    assert exact.rate_error_bound_ppm == pytest.approx(exact.rate_error_bound * 1e6)
    assert SampleClock(P.SAMPLE_PERIOD).rate_error_bound_ppm == pytest.approx(9.99e6)


@pytest.mark.parametrize('step', [-3600.0, +3600.0, -1.0, +1.0])
def test_a_host_clock_step_is_detected_and_the_stamps_stay_on_the_device_clock(step):
    clock, acquisition, stamps, raised = clock_run(0.002, step_at=8.0, step=step)
    assert len(clock.host_steps) == 1 and clock.host_steps[0] == pytest.approx(step, abs=0.01)
    assert clock.host_offset == pytest.approx(step, abs=0.01)
    assert raised is None
    spacing = np.diff(stamps) / P.SAMPLE_PERIOD
    assert spacing.min() > 0.55 and spacing.max() < 1.1          # no 1.227 ms spacing, no jump
    assert np.max(np.abs(stamps - acquisition - 0.001)[len(stamps) // 2:]) < 3e-3


def test_a_burst_after_a_paused_device_is_no_clock_fault():
    """The device link pauses 4 s early on (frames held, then drained in ~0.2 s): no rate fault, no host step."""
    period = P.SAMPLE_PERIOD
    clock = SampleClock(period)
    sequence, now = 0, 50.0
    for _ in range(60):                                   # 1.2 s of normal reads
        now += 10 * period
        clock.stamp_many(list(range(sequence, sequence + 10)), now + 0.001)
        sequence += 10
    start, first = now, sequence                          # the device keeps sampling from here on
    read_at, reads = now + 4.0, 0
    while True:                                           # the backlog drained 250 samples per read, 20 ms apart
        acquired = first + int((read_at - start) / period)
        block = list(range(sequence, min(acquired, sequence + 250)))
        clock.stamp_many(block, read_at + 0.001)
        sequence = block[-1] + 1
        reads += 1
        assert not clock.rate_fault and clock.host_steps == []
        if sequence >= acquired:
            break
        read_at += 0.02
    assert reads > 5
    now = read_at
    for _ in range(300):
        now += 10 * period
        clock.stamp_many(list(range(sequence, sequence + 10)), now + 0.001)
        sequence += 10
        assert not clock.rate_fault
    assert clock.host_steps == [] and clock.rate_verified


@pytest.mark.parametrize('seed', [3, 4])
def test_a_loaded_host_raises_no_clock_fault(seed):
    """A right clock read by a host under heavy load (reads 10-200 ms apart, delays of tens of ms with stalls of up
    to 0.4 s, and a backlog that builds up over 2 s and drains): no rate fault, no host step, ever."""
    rng = np.random.default_rng(seed)
    period = P.SAMPLE_PERIOD
    n = int(40.0 / period)
    acquisition = 10.0 + np.arange(n) * period * (1 + 300e-6)
    clock = SampleClock(period)
    start = 0
    while start < n:
        stop = min(n, start + int(rng.integers(5, 100)))
        delay = 0.001 + rng.exponential(0.03)
        if rng.random() < 0.02:
            delay += rng.uniform(0.1, 0.4)
        t = acquisition[stop - 1] - 10.0
        if 12.0 < t < 14.0:
            delay += 0.2 * (t - 12.0)              # falling behind, 0.4 s at worst
        clock.stamp_many(list(range(start, stop)), acquisition[stop - 1] + delay)
        assert not clock.rate_fault, (t, clock.rate_error, clock.rate_error_bound)
        start = stop
    assert clock.host_steps == [] and clock.rate_verified


def test_a_host_falling_behind_widens_the_rate_bound_it_reports():
    """A device 1.5 % slow read by a host that falls steadily behind: each read is stamped later after its port
    check (7.5 ms more every second: a reader thread starved on a loaded machine; CI once had '2.01 % slow ± 0.07 %'
    said for 1.50 %). A delay that grows looks like a slower clock; only the reader knows how long its bytes can
    have waited (the time since it last found the port drained). Told, the clock's ± covers the truth; not told,
    it does not (the case the bound exists for)."""
    period = P.SAMPLE_PERIOD
    truth = 0.015
    n = int(12.0 / period)
    acquisition = 10.0 + np.arange(n) * period * (1.0 + truth)

    def run(tell: bool) -> SampleClock:
        clock = SampleClock(period)
        checked_at, start = acquisition[0], 0
        while start < n:
            stop = min(n, start + 10)                     # the device writes 10 samples at once
            previous_check, checked_at = checked_at, acquisition[stop - 1] + 0.0002
            arrival = checked_at + 0.0075 * (acquisition[stop - 1] - 10.0)     # stamped later and later
            clock.stamp_many(list(range(start, stop)), arrival, arrival - previous_check if tell else None)
            start = stop
        return clock

    told, untold = run(True), run(False)
    assert untold.rate_verified and abs(untold.rate_error - truth) > untold.rate_error_bound    # the bug
    assert told.rate_verified and abs(told.rate_error - truth) <= told.rate_error_bound
    assert told.rate_error_bound < 0.01                # still a usable number: the fault is said
    assert told.rate_fault

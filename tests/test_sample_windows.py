"""The identification node's stream logic as a plain core class (issue #44): samples buffered, rejected with a
reason, restarts cleared and said once per condition, windows handed out every hop -- without ROS."""
from __future__ import annotations

import math

import pytest

from aeropend_core.diagnosis.sample_windows import STABLE_AFTER_RESTART, SampleWindows

STEP_NS = 2_000_000            # 500 Hz


def feed(stream: SampleWindows, sequences, offset_ns: int = 0) -> list:
    return [stream.add(n, offset_ns + n * STEP_NS, 1.0, 0.1, 0.01 * n) for n in sequences]


def test_bad_samples_are_rejected_with_their_reason_and_never_buffered():
    stream = SampleWindows(0.002)
    feed(stream, range(10))
    assert stream.add(10, 10 * STEP_NS, math.nan, 0.1, 0.0).rejected == 'not_finite'
    assert stream.add(9, 10 * STEP_NS, 1.0, 0.1, 0.0).rejected == 'duplicate'
    assert stream.add(3, 8 * STEP_NS, 1.0, 0.1, 0.0).rejected == 'out_of_order'
    arrival = stream.add(11, 9 * STEP_NS, 1.0, 0.1, 0.0)
    assert arrival.rejected == 'stamp_not_increasing' and 'sample 11' in arrival.detail
    assert stream.rejected == {'not_finite': 1, 'duplicate': 1, 'out_of_order': 1, 'stamp_not_increasing': 1,
                               'unreadable': 0}
    assert stream.sequence == list(range(10)) and stream.samples_received == 10 and stream.samples_missed == 0


def test_lost_samples_are_counted_not_filled():
    stream = SampleWindows(0.002)
    feed(stream, [*range(100), *range(105, 200)])
    assert stream.samples_missed == 5 and len(stream.stamps) == 195 and 100 not in stream.sequence


def test_a_restart_clears_the_buffer_and_a_condition_is_said_once():
    stream = SampleWindows(0.002)
    feed(stream, range(200))
    generation = stream.generation
    later = 200 * STEP_NS
    first = stream.add(0, later, 1.0, 0.1, 0.0)                # the counter went back with a later stamp
    assert first.restart_kind == 'counter' and first.new_condition and 'restarted' in first.restart
    assert stream.sequence == [0] and stream.generation == generation + 1 and stream.restarts == 1
    second = stream.add(1, later + 10 * 10**9, 1.0, 0.1, 0.0)  # stamps jump 10 s over one sample, same condition
    assert second.restart_kind == 'stamps' and not second.new_condition and stream.restarts == 2
    arrivals = feed(stream, range(2, 2 + STABLE_AFTER_RESTART + 1), offset_ns=later + 10 * 10**9 - STEP_NS)
    stable = [a for a in arrivals if a.stable_again]
    assert len(stable) == 1 and stable[0].restarts_in_condition == 2 and stream.restart_condition is None


@pytest.mark.parametrize('window_s, hop_s', [(4.0, 1.0), (2.0, 2.0)])
def test_windows_come_every_hop_and_keep_one_window_of_history(window_s, hop_s):
    stream = SampleWindows(0.002)
    windows = []
    for n in range(5000):                                      # 10 s
        stream.add(n, n * STEP_NS, 1.0, 0.1, 0.0)
        window = stream.due_window(n * STEP_NS, window_s, hop_s)
        if window is not None:
            windows.append(window)
    spans = [(w['stamp_ns'][-1] - w['stamp_ns'][0]) * 1e-9 for w in windows]
    last_s = 4999 * STEP_NS * 1e-9                             # the first window at window_s, then one per hop
    assert len(windows) == stream.windows_due == int((last_s - window_s) / hop_s) + 1
    assert all(abs(span - window_s) <= 0.002 for span in spans)
    assert all(len(w['angle']) == len(w['sequence']) == len(w['armature_current']) for w in windows)
    assert stream.buffered_span() <= window_s + hop_s

"""A rod held still by dry friction (or below the thrust that moves it) is not a frozen angle sensor (issue 40
item 3): on the second simulator's record 41002 (dry friction, 56 dB, 10-bit encoder) the angle holds one count for
up to 1.3 s while Va changes; the gate says so (``rod_held``, a warning) instead of refusing it. A real stuck
sensor on the same record (frozen while the rod moves, or frozen to the record's end) is still refused."""
from __future__ import annotations

import numpy as np
import pytest

from aeropend_core.io.recording import from_columns
from aeropend_core.signals.quality import DataQualityError, check_recording
from aeropend_core.testing import second_rig


@pytest.fixture(scope='module')
def held() -> dict[str, np.ndarray]:
    """Second-rig seed 41002 as the benchmark draws it: dry friction 6.7 rad/s^2 and a cable spring."""
    record = second_rig.draw(41002, effects=['friction_torque', 'cable_spring'])
    return {name: np.array(values, dtype=float) for name, values in record.columns.items()}


def gate(columns):
    return check_recording(from_columns(columns, source='rig.csv'))


def frozen_spans(angle: np.ndarray, samples: int) -> list[tuple[int, int]]:
    starts = np.concatenate(([0], np.flatnonzero(np.diff(angle) != 0) + 1))
    stops = np.concatenate((starts[1:], [angle.size])) - 1
    return [(int(a), int(b)) for a, b in zip(starts, stops) if b - a + 1 >= samples]


def test_rod_held_by_friction_is_said_not_refused(held):
    assert frozen_spans(held['angle'], 600), 'the record must hold the angle still for over 1.2 s'
    report = gate(held)
    codes = {(f.code, f.severity) for f in report.findings}
    assert ('rod_held', 'warning') in codes and not any(code == 'stuck_sensor' for code, _ in codes)
    message = next(f.message for f in report.findings if f.code == 'rod_held')
    assert 'held still' in message and 'frozen sensor' in message


def test_sensor_frozen_while_the_rod_moves_is_still_refused(held):
    angle, rate = held['angle'], int(round(1 / np.median(np.diff(held['t']))))
    start = next(i for i in range(5 * rate, angle.size - 3 * rate)
                 if abs(angle[i + 2 * rate] - angle[i]) > 0.1)       # the rod moves 0.1 rad within the next 2 s
    columns = {**held, 'angle': angle.copy()}
    columns['angle'][start:start + 2 * rate] = angle[start]
    with pytest.raises(DataQualityError) as caught:
        gate(columns)
    assert caught.value.finding.code == 'stuck_sensor'


def test_sensor_frozen_to_the_end_is_still_refused(held):
    """Entered from rest like a held rod, but with no thaw to tell the two apart: refused."""
    first, _ = frozen_spans(held['angle'], 600)[0]
    columns = {**held, 'angle': held['angle'].copy()}
    columns['angle'][first:] = held['angle'][first]
    with pytest.raises(DataQualityError) as caught:
        gate(columns)
    assert caught.value.finding.code == 'stuck_sensor'


def test_frozen_angle_without_quantisation_is_still_refused(held):
    """An unquantised reading shows its noise while the rod is still: a held value is a stuck sensor."""
    rng = np.random.default_rng(0)
    angle = held['angle'] + rng.uniform(-0.5, 0.5, held['angle'].size) * second_rig.ANGLE_COUNT
    first, last = frozen_spans(held['angle'], 600)[0]
    angle[first:last + 1] = angle[first]
    with pytest.raises(DataQualityError) as caught:
        gate({**held, 'angle': angle})
    assert caught.value.finding.code == 'stuck_sensor'

"""The candidates of a search round fitted side by side (aeropend_core.parallel, issue 41): the answer does
not depend on the number of workers.

The diagnosis with one worker is the old code path (the candidates one after the other); with two the fits run on
two threads at once. Verdicts, parameters and their +- must be equal exactly (not within a tolerance: each fit does
the same arithmetic), on records with a known hidden effect that the diagnosis must also name.
"""
from __future__ import annotations

import threading

import numpy as np
import pytest

from aeropend_core.parallel import WORKERS_VARIABLE, default_workers, map_in_order
from aeropend_core.errors import AeropendError


def test_map_in_order_keeps_the_order_and_raises_the_first_error():
    assert map_in_order(lambda x: x * x, range(7), workers=3) == [x * x for x in range(7)]
    assert map_in_order(lambda x: x, [], workers=2) == []

    def fails(x):
        if x in (2, 5):
            raise ValueError(f'item {x}')
        return x
    with pytest.raises(ValueError, match='item 2'):
        map_in_order(fails, range(7), workers=2)


def test_a_map_inside_a_worker_runs_in_that_worker():
    both_started = threading.Barrier(2, timeout=60)       # the two outer items run at once

    def inner(_):
        both_started.wait()
        return set(map_in_order(lambda y: threading.current_thread().name, range(3), workers=2))
    outer = map_in_order(inner, range(2), workers=2)
    names = set().union(*outer)
    assert len(names) == 2 and all(name.startswith('aeropend-fit') for name in names)   # no nested pool
    assert all(len(found) == 1 for found in outer)


def test_the_workers_variable(monkeypatch):
    monkeypatch.setenv(WORKERS_VARIABLE, '3')
    assert default_workers() == 3
    for bad in ('0', 'two', '-1'):
        monkeypatch.setenv(WORKERS_VARIABLE, bad)
        with pytest.raises(AeropendError, match=WORKERS_VARIABLE):
            default_workers()
    monkeypatch.delenv(WORKERS_VARIABLE)
    assert default_workers() >= 1


def _without_times(value):
    """The diagnosis as JSON without its wall-clock fields (they differ from run to run)."""
    if isinstance(value, dict):
        return {k: _without_times(v) for k, v in value.items() if k not in ('seconds', 'elapsed_s')}
    if isinstance(value, list):
        return [_without_times(v) for v in value]
    return value


@pytest.mark.slow
@pytest.mark.parametrize('hidden, named', [({'thrust_lag': 0.15}, 'thrust_lag'),
                                           ({'angle_offset': 0.05}, 'angle_offset')])
def test_the_diagnosis_is_the_same_with_one_and_two_workers(hidden, named, monkeypatch):
    from aeropend_core.diagnosis import stages
    from aeropend_core.diagnosis.diagnose import diagnose
    from aeropend_core.io.recording import from_columns
    from aeropend_core.present.verdict_text import diagnosis_dict
    from aeropend_core.sim.excitation import lhc_schedule
    from aeropend_core.sim.noise import MeasurementNoise
    from aeropend_core.sim.simulate import simulate
    duty = lhc_schedule(25.0, seed=4).duty(duration=25.0)
    trajectory = simulate(duty, effects=hidden, noise=MeasurementNoise(40.0, True), seed=4)
    recording = from_columns(trajectory.columns(with_truth=False))
    threads: set[str] = set()
    original = stages._try

    def spying(*args, **kwargs):
        threads.add(threading.current_thread().name)
        return original(*args, **kwargs)
    monkeypatch.setattr(stages, '_try', spying)
    results = {}
    for workers in (1, 2):
        monkeypatch.setenv(WORKERS_VARIABLE, str(workers))
        threads.clear()
        result = diagnose(recording, candidates=['thrust_lag', 'angle_filter', 'angle_offset', 'coulomb_friction'],
                          drift=False, discovery=False)
        results[workers] = (result, _without_times(diagnosis_dict(result)), set(threads))
    serial, parallel = results[1], results[2]
    assert serial[2] == {threading.current_thread().name}            # one worker: in this thread, as before
    assert len({t for t in parallel[2] if t.startswith('aeropend-fit')}) == 2      # two at once (a round of one
    # candidate, or a rival tried alone, runs in this thread)
    assert serial[0].missing_effect == named == parallel[0].missing_effect         # the known truth is named
    for one, two in zip(serial[0].candidates, parallel[0].candidates):
        assert one.effect == two.effect
        np.testing.assert_equal(one.parameters, two.parameters)         # exact; NaN equal to NaN
        np.testing.assert_equal(one.standard_errors, two.standard_errors)
        np.testing.assert_equal(one.delta_bic, two.delta_bic)
    np.testing.assert_equal(serial[1], parallel[1])           # everything the JSON says, exactly


def test_a_kernel_split_over_threads_by_segments_gives_the_numbers_of_one_call(monkeypatch):
    """A long record's fits run one after the other; their kernels run chunks of the segments on threads
    (parallel.in_segment_chunks). The simulation (two rows, lag and gate on) and the exact Jacobian with 3 workers
    equal those of one worker bit for bit, and the segments went to the threads in 3 chunks."""
    from aeropend_core.diagnosis import output_error as oe
    rng = np.random.default_rng(7)
    n = 40_000
    voltage = np.repeat(rng.uniform(0.3, 2.4, n // 150 + 1), 150)[:n]
    current = 0.2 * voltage + 0.01 * rng.standard_normal(n)
    angle = 0.01 * rng.standard_normal(n)
    segments = [(start, start + length) for start, length in zip(range(0, n, 4000), rng.integers(2000, 4000, 10))]
    data = oe.SegmentedData(voltage, current, angle, segments, 1.0 / 490.0)
    structure = oe.Structure(('coulomb_friction', 'thrust_lag', 'dead_zone'))
    values = {'gravity_stiffness': 40.0, 'damping': 1.2, 'thrust_gain': 30.0, 'armature_resistance': 0.9,
              'friction_acceleration': 0.5, 'time_constant': 0.05, 'threshold_voltage': 0.6}
    rows = np.array([structure.row(values), structure.row({**values, 'damping': 1.5})])
    initial = rng.normal(0.0, 0.3, (2, len(data.segments), 2))
    exact = oe.exact_columns(structure, tuple(values))
    chunks = []
    kernel = oe._simulate_kernel

    def spying(*args):
        chunks.append((threading.current_thread().name, len(args[4])))
        return kernel(*args)
    monkeypatch.setattr(oe, '_simulate_kernel', spying)
    results = {}
    for workers in (1, 3):
        monkeypatch.setenv(WORKERS_VARIABLE, str(workers))
        chunks.clear()
        simulated = data.simulate(structure, rows, initial)
        jacobian = oe._exact_jacobian(data, structure, rows[0], initial[0], exact, np.ones(len(exact)),
                                      angle[data.residual_index])
        results[workers] = (simulated, jacobian[0], jacobian[1], list(chunks))
    np.testing.assert_array_equal(results[1][0], results[3][0])
    np.testing.assert_array_equal(results[1][1], results[3][1])
    np.testing.assert_array_equal(results[1][2], results[3][2])
    assert results[1][3] == [(threading.current_thread().name, len(data.segments))]      # one call, in this thread
    assert len(results[3][3]) == 3 and all(name.startswith('aeropend-kernel') for name, _ in results[3][3])
    assert sum(count for _, count in results[3][3]) == len(data.segments)


@pytest.mark.skipif(not hasattr(__import__('os'), 'fork'), reason='fork only')
def test_a_forked_child_runs_split_kernels_on_threads_of_its_own(monkeypatch):
    """The kernel threads' pool is the parent's; a forked child has none of its threads, and could wait for
    chunks nobody runs (when the parent's threads were all idle): the child forgets the pool and starts its own."""
    import os
    import signal

    from aeropend_core import parallel
    monkeypatch.setenv(WORKERS_VARIABLE, '2')
    seen = []
    parallel.in_segment_chunks(lambda a, b: seen.append((a, b)), [0, 5000], [5000, 10000])   # the pool exists
    assert sorted(seen) == [(0, 1), (1, 2)]
    pid = os.fork()
    if pid == 0:           # the child: exit 0 only if it forgot the parent's pool and its own split call finishes
        forgotten = parallel._kernel_pool is None
        signal.alarm(30)                             # a child left waiting is killed (status non-zero), not hung
        try:
            parallel.in_segment_chunks(lambda a, b: None, [0, 5000], [5000, 10000])
        finally:
            os._exit(0 if forgotten and parallel._kernel_pool is not None else 1)
    _, status = os.waitpid(pid, 0)
    assert os.waitstatus_to_exitcode(status) == 0


def test_the_motor_observer_and_its_ensemble_are_the_same_with_one_and_two_workers(monkeypatch):
    """The observer's Jacobian columns and the back-EMF ensemble's members are simulated on the worker threads
    (signals.motor, issue 41): the fit, its back-EMF, the members and the standard errors with two workers equal
    those of one bit for bit, and with two workers the kernel ran on two threads."""
    from aeropend_core.signals import motor
    from aeropend_core.signals.preprocess import detect_steps, piecewise_constant
    from aeropend_core.sim.excitation import lhc_schedule
    from aeropend_core.sim.noise import MeasurementNoise
    from aeropend_core.sim.simulate import simulate
    duty = lhc_schedule(20.0, duty_range=(0.0, 0.7), duty_cap=0.7, seed=11).duty(duration=20.0)
    record = simulate(duty, noise=MeasurementNoise(40.0, True), seed=12)
    steps = detect_steps(record.armature_voltage, record.sample_time)
    voltage = piecewise_constant(record.armature_voltage, steps)
    threads: set[str] = set()
    kernel = motor._motor_kernel

    def spying(*args):
        threads.add(threading.current_thread().name)
        return kernel(*args)
    monkeypatch.setattr(motor, '_motor_kernel', spying)
    results = {}
    for workers in (1, 2):
        monkeypatch.setenv(WORKERS_VARIABLE, str(workers))
        threads.clear()
        fit = motor.fit_motor(voltage, record.armature_current, steps, record.sample_time)
        members, errors = motor.back_emf_ensemble(fit, voltage, record.armature_voltage, record.armature_current,
                                                  steps, record.sample_time, with_errors=True)
        results[workers] = (fit, members, errors, set(threads))
    one, two = results[1], results[2]
    assert one[0].kind == 'inductance' and one[1] is not None
    assert one[3] == {threading.current_thread().name}
    assert len({name for name in two[3] if name.startswith('aeropend-fit')}) == 2
    assert one[0].parameters == two[0].parameters and one[0].solution == two[0].solution
    np.testing.assert_array_equal(one[0].back_emf, two[0].back_emf)
    np.testing.assert_array_equal(one[1], two[1])
    assert one[2] == two[2]

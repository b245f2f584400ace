"""One effect, one record; one vocabulary of parameter names.

* every built-in effect is named in at most 2 library files, one of them its record (``aeropend_core/model/
  effects.py``); command-line examples and demo defaults (``cli/`` packages) are documentation, not library;
* parameter names are unique across the catalog and the nominal model, and every estimator reports the nominal
  parameters under the same names;
* an effect declared through ``register_effect`` with kernel terms (the README's few lines) runs in the compiled
  simulator and is found by the diagnosis, like a built-in one.
"""
import re
from pathlib import Path

import numpy as np
import pytest

from aeropend_core.model.effects import CATALOG, EffectParameter, register_effect
from aeropend_core.model.names import NOMINAL_PARAMETERS
from aeropend_core.present.summary import format_summary

ROOT = Path(__file__).resolve().parents[1]
RECORD = 'aeropend_core/model/effects.py'


def library_files():
    for package in ('aeropend_core', 'aeropend_ros'):
        for path in sorted((ROOT / package).rglob('*.py')):
            if 'cli' not in path.relative_to(ROOT).parts:
                yield path


@pytest.mark.parametrize('effect', sorted(name for name, e in CATALOG.items() if e.builtin))
def test_builtin_effect_is_named_in_its_record_and_at_most_one_kernel_module(effect):
    pattern = re.compile(rf'\b{effect}\b')
    files = [str(path.relative_to(ROOT)) for path in library_files() if pattern.search(path.read_text())]
    assert RECORD in files
    assert len(files) <= 2, files


def test_parameter_names_are_unique_and_none_shadows_a_nominal_one():
    names = [p for effect in CATALOG.values() for p in effect.parameter_names]
    assert len(names) == len(set(names))
    assert not set(names) & set(NOMINAL_PARAMETERS)


def test_every_estimator_reports_the_nominal_parameters_under_the_same_names():
    from aeropend_core.diagnosis.output_error import Structure
    from aeropend_core.identify.pendulum import identify_pendulum
    from aeropend_core.sim.excitation import lhc_schedule
    from aeropend_core.sim.simulate import simulate
    run = simulate(lhc_schedule(20.0, seed=2).duty(duration=20.0), effects={'angle_offset': 0.05})
    weak = identify_pendulum(run.time, run.armature_voltage, run.armature_current, run.angle, duty=run.duty,
                             effects=['angle_offset'])
    assert weak.estimator == 'weak_sindy'
    assert set(NOMINAL_PARAMETERS) <= set(weak.parameters)
    assert weak.parameters['angle_offset'] == pytest.approx(0.05, abs=0.005)
    assert Structure(('angle_offset',)).parameter_names == (*NOMINAL_PARAMETERS, 'angle_offset')


@pytest.mark.slow
def test_an_effect_declared_in_a_few_lines_runs_compiled_and_is_diagnosed(scoped_catalog):
    from aeropend_core.diagnosis.diagnose import diagnose
    from aeropend_core.io.recording import from_columns
    from aeropend_core.sim.excitation import lhc_schedule
    from aeropend_core.sim.noise import MeasurementNoise
    from aeropend_core.sim.simulate import RigSimulator, simulate

    @register_effect('test_pivot_drag', 'drag of a greased pivot, growing with the square of the speed',
                     parameters=[EffectParameter('pivot_drag', '1/rad', 'drag per unit inertia', 4.0, 0.0, 100.0)],
                     kernel_terms=(('rate_square', 'pivot_drag'),), replace=True,
                     separated_from={'damping': 'add larger, faster swings'})
    def pivot_drag(angle, angular_rate, pivot_drag):
        return -pivot_drag * angular_rate * np.abs(angular_rate)

    assert RigSimulator(effects={'test_pivot_drag': 4.0}).method == 'compiled'
    duty = lhc_schedule(40.0, seed=9).duty(duration=40.0)
    compiled = simulate(duty, effects={'test_pivot_drag': 4.0})
    reference = simulate(duty, effects={'test_pivot_drag': 4.0}, method='lsoda')
    assert np.max(np.abs(compiled.angle - reference.angle)) < 1e-4
    noisy = simulate(duty, effects={'test_pivot_drag': 4.0}, noise=MeasurementNoise(40.0, True), seed=10)
    found = diagnose(from_columns(noisy.columns(with_truth=False)),
                     candidates=['test_pivot_drag', 'coulomb_friction'])
    assert found.candidates[0].effect == 'test_pivot_drag', format_summary(found)
    assert found.candidates[0].parameters['pivot_drag'] == pytest.approx(4.0, rel=0.15)

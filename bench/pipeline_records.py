"""Records that exercise every path of the diagnosis, for checking a refactor of the pipeline byte for byte.

Writes CSVs (measured columns only; 40 dB, 10-bit quantisation) to a folder:

* ``clean.csv`` -- nothing hidden (seed 5);
* ``coulomb.csv`` -- one catalog effect (Coulomb friction 4 rad/s^2, seed 5);
* ``two.csv`` -- two catalog effects (Coulomb 4 + thrust lag 0.15 s, seed 31): diagnosed plain and with
  ``--add coulomb_friction`` (the second round);
* ``cable_small.csv`` -- a cable spring at small angles (duty <= 0.3, seed 41): confounded with gravity;
* ``encoder.csv`` -- an encoder second harmonic 0.04 sin(2 angle) (seed 11): a catalog set (offset + cable) and a
  discovered term confounded;
* ``inflow.csv`` -- thrust falling with the rod's rate (bench/discovery_effects.py's ``test_inflow`` 0.05, seed 11):
  a pendulum term outside the catalog;
* ``brush.csv``, ``heating.csv``, ``reaction.csv`` -- motor effects outside the catalog
  (:mod:`aeropend_core.testing.motor_rigs`: brush drop 0.15 V, heating R_th 40 K/W tau 20 s, armature reaction
  beta 0.1 1/A; bench/discovery.py's sizes; seed 11);
* ``joint_a.csv``, ``joint_b.csv`` -- two 40 s records with Coulomb friction 4 (seeds 7, 8) diagnosed together;
* ``clean_SEED.csv`` -- bench/false_alarms.py's clean records (``--clean N`` of them from seed 9000).

Run:  PYTHONPATH=. .venv/bin/python bench/pipeline_records.py OUT_FOLDER [--clean 10]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))


def _simulated(effects, seed, duration=60.0, max_duty=0.7, module=None, register=None):
    from aeropend_core.model.effects import CATALOG, load_effects_module
    from aeropend_core.sim.excitation import lhc_schedule
    from aeropend_core.sim.noise import MeasurementNoise
    from aeropend_core.sim.simulate import simulate
    builtin = set(CATALOG)
    if module:
        load_effects_module(module)
    if register:
        register()
    try:
        schedule = lhc_schedule(duration, duty_range=(0.0, max_duty), duty_cap=max_duty, seed=seed)
        trajectory = simulate(schedule.duty(duration=duration), effects=effects,
                              noise=MeasurementNoise(psnr_db=40.0, quantise=True), seed=seed + 1)
    finally:
        for name in set(CATALOG) - builtin:
            CATALOG.pop(name)
    return trajectory.columns(with_truth=False)


def _encoder():
    from aeropend_core.model.effects import MEASUREMENT, EffectParameter, register_effect
    register_effect('test_encoder_harmonic', 'encoder second-harmonic nonlinearity', kind=MEASUREMENT, replace=True,
                    parameters=[EffectParameter('test_encoder_amplitude', 'rad', 'amplitude', 0.04, -1.0, 1.0)])(
        lambda angle, test_encoder_amplitude: angle + test_encoder_amplitude * np.sin(2.0 * angle))


def _motor(effect, size, seed=11, **options):
    from aeropend_core.sim.excitation import lhc_schedule
    from aeropend_core.sim.noise import MeasurementNoise
    from aeropend_core.testing.motor_rigs import simulate_motor_effect
    duty = lhc_schedule(60.0, duty_range=(0.0, 0.7), duty_cap=0.7, seed=seed).duty(duration=60.0)
    trajectory = simulate_motor_effect(duty, effect, size, noise=MeasurementNoise(psnr_db=40.0, quantise=True),
                                       seed=seed + 1, **options)
    return trajectory.columns(with_truth=False)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0], allow_abbrev=False)
    parser.add_argument('out', help='folder for the CSVs')
    parser.add_argument('--clean', type=int, default=0, help="bench/false_alarms.py's clean records to write too")
    args = parser.parse_args()
    from aeropend_core.io.recording import write_csv
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    module = str(ROOT / 'discovery_effects.py')
    records = {
        'clean': lambda: _simulated(None, 5),
        'coulomb': lambda: _simulated({'coulomb_friction': 4.0}, 5),
        'two': lambda: _simulated({'coulomb_friction': 4.0, 'thrust_lag': 0.15}, 31),
        'cable_small': lambda: _simulated({'cable_torque': 20.0}, 41, max_duty=0.3),
        'encoder': lambda: _simulated({'test_encoder_harmonic': 0.04}, 11, register=_encoder),
        'inflow': lambda: _simulated({'test_inflow': 0.05}, 11, module=module),
        'brush': lambda: _motor('brush_drop', 0.15),
        'heating': lambda: _motor('heating', 40.0, time_constant=20.0),
        'reaction': lambda: _motor('armature_reaction', 0.1),
        'joint_a': lambda: _simulated({'coulomb_friction': 4.0}, 7, duration=40.0),
        'joint_b': lambda: _simulated({'coulomb_friction': 4.0}, 8, duration=40.0),
    }
    for name, make in records.items():
        target = out / f'{name}.csv'
        if not target.exists():
            write_csv(str(target), make())
            print(f'wrote {target}', flush=True)
    if args.clean:
        from false_alarms import record
        for seed in range(9000, 9000 + args.clean):
            target = out / f'clean_{seed}.csv'
            if not target.exists():
                recording, _ = record(seed)
                write_csv(str(target), {'t': recording.time, **recording.signals})
                print(f'wrote {target}', flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())

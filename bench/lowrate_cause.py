"""Where the output-error fit's low-rate bias comes from (issue #21: damping +14 % at 98 Hz, +58 % at 24.5 Hz).

The record of bench/rate_sweep.py (default rig, Latin hypercube, 40 dB, 10-bit, 30 s, seed 11) is decimated by
keeping every Nth sample. Per rate, the nominal model is fitted by output error (the training part, as
``diagnose`` does) with the thrust input and the angle taken from different places, so that each link of the chain
is tried alone:

* ``diagnose``: as the tool runs (the motor observer's back-EMF, or Va - R Ia when the observer is inadequate;
  the measured angle);
* ``true e``: the simulator's true back-EMF Kw w1 at the samples as the thrust input (the observer taken out);
* ``true e, true y``: that and the noise-free angle (what is left is the integrator and the segmenting);
* ``observer, true y``: the tool's input with the noise-free angle.

It also prints the motor observer at each rate: its kind, fitted Rm (truth 1.08 ohm), and the error of its
back-EMF against the truth (mean, RMS [V]; thrust ratio: least-squares scale of e|e| against the true e|e|).

Usage:
  nice -n 10 python bench/lowrate_cause.py --out bench/results/2026-11-27-lowrate/cause.json
"""
from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from rate_sweep import DURATION, MeasurementNoise, lhc_schedule, simulate  # noqa: E402

from aeropend_core.diagnosis.compare import fit_model, prepare  # noqa: E402
from aeropend_core.io.recording import Recording  # noqa: E402
from aeropend_core.model.parameters import DEFAULT_PARAMETERS as P  # noqa: E402

EVERY = (1, 2, 5, 10, 20)
TRUTH = {'gravity_stiffness': P.gravity_stiffness, 'damping': P.damping, 'thrust_gain': P.thrust_gain}


def errors(prep) -> dict[str, float]:
    """Relative errors [1] of the nominal output-error fit on `prep`'s training part."""
    fitted = fit_model(prep, ()).parameters
    return {name: round(fitted[name] / truth - 1.0, 4) for name, truth in TRUTH.items()}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--out', default='-')
    parser.add_argument('--every', type=int, nargs='*', default=list(EVERY))
    options = parser.parse_args()
    duty = lhc_schedule(DURATION, seed=11).duty(duration=DURATION)
    columns = simulate(duty, noise=MeasurementNoise(40.0, True), seed=11).columns(with_truth=True)
    rows = []
    for every in options.every:
        pick = slice(None, None, every)
        recording = Recording(np.asarray(columns['t'][pick]),
                              {k: np.asarray(columns[k][pick], dtype=float)
                               for k in ('duty', 'armature_voltage', 'armature_current', 'angle')}, source='sweep')
        prep = prepare(recording)
        true_emf = P.back_emf_constant * np.asarray(columns['true_motor_speed'][pick], dtype=float)
        true_angle = np.asarray(columns['true_angle'][pick], dtype=float)
        emf = prep.motor.back_emf if prep.motor is not None else prep.voltage - P.armature_resistance * prep.current
        thrust, true_thrust = emf * np.abs(emf), true_emf * np.abs(true_emf)
        with_true_emf = replace(prep, voltage=true_emf, current=np.zeros_like(true_emf), voltage_ensemble=None)
        row = {'rate_hz': round(490.0 / every, 2),
               'observer': None if prep.motor is None else {
                   'kind': prep.motor.kind, 'motor_resistance_ohm': round(prep.motor.parameters['motor_resistance'], 4),
                   'current_rms_error_a': round(prep.motor.current_rms_error, 4),
                   'current_noise_rms_a': round(prep.motor.current_noise_rms, 4)},
               'emf_error_mean_v': round(float(np.mean(emf - true_emf)), 4),
               'emf_error_rms_v': round(float(np.sqrt(np.mean((emf - true_emf) ** 2))), 4),
               'thrust_ratio': round(float(thrust @ true_thrust / (true_thrust @ true_thrust)), 4),
               'diagnose': errors(prep),
               'true e': errors(with_true_emf),
               'true e, true y': errors(replace(with_true_emf, angle=true_angle, angle_step=0.0)),
               'observer, true y': errors(replace(prep, angle=true_angle, angle_step=0.0))}
        rows.append(row)
        print(json.dumps(row), file=sys.stderr, flush=True)
    if options.out != '-':
        Path(options.out).write_text(json.dumps(rows, indent=1) + '\n')
    else:
        print(json.dumps(rows, indent=1))
    return 0


if __name__ == '__main__':
    sys.exit(main())

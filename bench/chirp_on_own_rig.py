"""Does a continuously varying input (a duty chirp) leave the nominal model unbiased on aeropend's own simulator?

A clean 40 s record of the default rig (``aeropend_core.sim.simulate``, PSNR 55 dB, 10-bit quantisation) under a
linear duty chirp 0.1 Hz -> F Hz around duty 0.27 +- 0.18 (rest for the first 0.5 s); the nominal fit (no effect, no
search): error beyond the noise and each nominal parameter's relative error and z against the truth. Earlier
coverage benchmarks used duty steps only.

Run:  nice -n 19 .venv/bin/python bench/chirp_on_own_rig.py [--top 2.5 1.0]   (a few seconds per record)
"""
from __future__ import annotations

import argparse


def main() -> None:
    import numpy as np
    from threadpoolctl import threadpool_limits

    from aeropend_core.diagnosis.compare import excess_error
    from aeropend_core.diagnosis.diagnose import diagnose
    from aeropend_core.io.recording import from_columns
    from aeropend_core.model.parameters import DEFAULT_PARAMETERS as rig
    from aeropend_core.sim.noise import MeasurementNoise
    from aeropend_core.sim.simulate import simulate
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--top', type=float, nargs='+', default=[2.5, 1.0], help='end frequencies of the chirp [Hz]')
    args = parser.parse_args()
    time = np.arange(int(40 * 490)) / 490.0
    truth = {name: getattr(rig, name) for name in ('gravity_stiffness', 'damping', 'thrust_gain',
                                                   'armature_resistance')}
    for top in args.top:
        duty = np.clip(0.27 + 0.18 * np.sin(2 * np.pi * (0.1 * time + (top - 0.1) / 80 * time ** 2)), 0.0, 0.6)
        duty[:245] = 0.0
        trajectory = simulate(duty, rig, noise=MeasurementNoise(55.0, True), seed=3)
        with threadpool_limits(1):
            found = diagnose(from_columns(trajectory.columns(with_truth=False), source='chirp'), candidates=(),
                             drift=False, discovery=False)
        values, errors = found.reported_parameters(found.current), found.reported_errors(found.current)
        beyond = excess_error(found.current.rms_error, found.current.noise_rms)
        print(f'chirp 0.1-{top:g} Hz: beyond the noise {1e3 * beyond:.2f} mrad (noise '
              f'{1e3 * found.current.noise_rms:.2f} mrad); ' + '; '.join(
                  f'{name} {100 * (values[name] / value - 1):+.1f} % (z {(values[name] - value) / errors[name]:+.1f})'
                  for name, value in truth.items()))


if __name__ == '__main__':
    main()

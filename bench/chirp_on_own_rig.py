"""Does a continuously varying input (a duty chirp) leave the nominal model unbiased on aeropend's own simulator?

A 40 s record of the default rig (``aeropend_core.sim.simulate``, 10-bit quantisation) under a linear duty chirp
0.1 Hz -> F Hz around duty 0.27 +- 0.18 (rest for the first 0.5 s); the nominal fit (no effect, no search): error
beyond the noise and each nominal parameter's relative error and z against the truth. Earlier coverage benchmarks
used duty steps only. Without --records: seed 3 at 55 dB for each --top (the record of session 18). With
--records N: N records from --seed-base on, each with its own top frequency (1 or 2.5 Hz) and PSNR U(30, 60) dB
drawn from its seed, one line each, then the share of records within 1 and 2 sigma of the truth per parameter.

Run:  nice -n 19 .venv/bin/python bench/chirp_on_own_rig.py [--top 2.5 1.0] [--records 40 --seed-base 300]
(10-20 s per record)
"""
from __future__ import annotations

import argparse

NAMES = ('gravity_stiffness', 'damping', 'thrust_gain', 'armature_resistance')


def fit_chirp(top: float, psnr_db: float, seed: int):
    """The nominal fit of one chirp record: (beyond the noise [rad], noise [rad], {name: (relative error, z)})."""
    import numpy as np
    from threadpoolctl import threadpool_limits

    from aeropend_core.diagnosis.compare import excess_error
    from aeropend_core.diagnosis.diagnose import diagnose
    from aeropend_core.io.recording import from_columns
    from aeropend_core.model.parameters import DEFAULT_PARAMETERS as rig
    from aeropend_core.sim.noise import MeasurementNoise
    from aeropend_core.sim.simulate import simulate
    time = np.arange(int(40 * 490)) / 490.0
    duty = np.clip(0.27 + 0.18 * np.sin(2 * np.pi * (0.1 * time + (top - 0.1) / 80 * time ** 2)), 0.0, 0.6)
    duty[:245] = 0.0
    trajectory = simulate(duty, rig, noise=MeasurementNoise(psnr_db, True), seed=seed)
    with threadpool_limits(1):
        found = diagnose(from_columns(trajectory.columns(with_truth=False), source='chirp'), candidates=(),
                         drift=False, discovery=False)
    values, errors = found.reported_parameters(found.current), found.reported_errors(found.current)
    beyond = excess_error(found.current.rms_error, found.current.noise_rms)
    return beyond, found.current.noise_rms, {
        name: (values[name] / getattr(rig, name) - 1, (values[name] - getattr(rig, name)) / errors[name])
        for name in NAMES}


def line(top: float, psnr_db: float, seed: int, result) -> str:
    beyond, noise, parameters = result
    return (f'seed {seed}, chirp 0.1-{top:g} Hz, {psnr_db:.1f} dB: beyond the noise {1e3 * beyond:.2f} mrad (noise '
            f'{1e3 * noise:.2f} mrad); ' + '; '.join(f'{name} {100 * rel:+.1f} % (z {z:+.1f})'
                                                     for name, (rel, z) in parameters.items()))


def main() -> None:
    import numpy as np
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--top', type=float, nargs='+', default=[2.5, 1.0], help='end frequencies of the chirp [Hz]')
    parser.add_argument('--records', type=int, default=0, help='records with drawn top and PSNR (0: the fixed ones)')
    parser.add_argument('--seed-base', type=int, default=300, help='first seed of --records')
    args = parser.parse_args()
    if not args.records:
        for top in args.top:
            print(line(top, 55.0, 3, fit_chirp(top, 55.0, 3)), flush=True)
        return
    z = {name: [] for name in NAMES}
    for seed in range(args.seed_base, args.seed_base + args.records):
        draw = np.random.default_rng(seed)
        top, psnr_db = float(draw.choice([1.0, 2.5])), float(draw.uniform(30.0, 60.0))
        result = fit_chirp(top, psnr_db, seed)
        print(line(top, psnr_db, seed, result), flush=True)
        for name, (_, score) in result[2].items():
            z[name].append(abs(score))
    print(f'\n{args.records} records, share within 1 sigma / 2 sigma of the truth:')
    for name, scores in z.items():
        scores = np.asarray(scores)
        print(f'  {name}: {100 * np.mean(scores <= 1):.0f} % / {100 * np.mean(scores <= 2):.0f} % '
              f'(largest |z| {scores.max():.1f})')


if __name__ == '__main__':
    main()

"""Why a small thrust lag is missed: the evidence behind each verdict, per seed (issue #11).

For bench/robustness.py's records with a thrust lag hidden (same schedules and noise seeds, 40 dB) the diagnosis
is run with the measurement chain known (``fixed={'angle_filter': 0}``, as ``--fix angle_filter=0``) and the
thrust_lag candidate's evidence is printed: its estimate, parameter t (HAC), training BIC, held-out
Diebold-Mariano, the share of the held-out error beyond the noise it removes, that error in units of its own
noise-power spread (``beyond_spread``), and how far the nominal parameters move when it is added.

It also prints the share against a low-variance estimate of the model's error beyond the noise: the mean
autocovariance of the held-out residual at lags 1-5 (white measurement noise adds nothing there; a model error,
slow, is nearly unchanged over 5 samples = 20 ms). ``--clean SEEDS`` does the same for bench/false_alarms.py's
clean records, listing every candidate that passes the statistical tests: if such an accurate share named the
small lag, would it also name what soaks up the nominal model's imperfection on clean records?

Run:  .venv/bin/python bench/lag_evidence.py [--factor 0.0625] [--seeds 1,2,3,4] [--clean 9000,9006]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
for path in (ROOT, ROOT / 'bench'):
    if str(path) not in sys.path:
        sys.path.insert(0, str(path))

LAGS = 5


def model_error_power(prep, comparison) -> float:
    """Mean autocovariance [rad^2] of the held-out residual at lags 1..LAGS (the model error's power)."""
    index = prep.heldout.residual_index
    residual = prep.angle[index] - comparison.evaluation.simulated[index]
    n = residual.size
    return float(np.mean([np.mean(residual[:n - k] * residual[k:]) for k in range(1, LAGS + 1)]))


def describe(tag: str, recording, fixed=None, only: str | None = None) -> None:
    from aeropend_core.diagnosis.diagnose import BIC_MARGIN, T_MIN, beyond_spread, diagnose
    from aeropend_core.diagnosis.doubts import parameter_moves
    found = diagnose(recording, fixed=fixed, drift=False)
    noise2 = found.noise_rms ** 2
    spread = beyond_spread(found.prepared)
    beyond = found.current.rms_error ** 2 - noise2
    power = model_error_power(found.prepared, found.current)
    print(f'{tag}: {found.verdict} {found.missing_effects}; error beyond the noise {beyond / noise2 * 100:.2f} % of '
          f'the noise variance = {beyond / spread:.2f} x its spread ({spread / noise2 * 100:.2f} %); autocovariance '
          f'estimate {power / noise2 * 100:.2f} %', flush=True)
    for c in found.candidates:
        if c.comparison is None or (only and c.effect != only) or (
                not only and not (c.t_statistic >= T_MIN and c.delta_bic < -BIC_MARGIN and c.dm_statistic >= 1.0)):
            continue
        moves = ', '.join(f'{name} {change * 100:+.1f} %' for name, _, _, change in
                          parameter_moves(found.current.parameters, c.comparison.parameters)[:3])
        values = ', '.join(f'{k} {v:.4g} +- {c.standard_errors.get(k, float("nan")):.2g}'
                           for k, v in c.parameters.items())
        print(f'    {c.effect}: {values}; t {c.t_statistic:.1f}, BIC {c.delta_bic:+.0f}, DM {c.dm_statistic:+.2f}, '
              f'gain {c.mse_gain / noise2 * 100:.2f} % of the noise variance, share {c.share_removed * 100:.0f} % '
              f'(autocovariance share {c.mse_gain / max(power, 1e-30) * 100:.0f} %), significant {c.significant}; '
              f'nominal moves: {moves or "< 1 %"}', flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--factor', type=float, default=1 / 16, help='lag as a multiple of the typical 0.15 s')
    parser.add_argument('--seeds', default='1,2,3,4', help='robustness.py seeds (comma-separated)')
    parser.add_argument('--psnr', type=float, default=40.0)
    parser.add_argument('--clean', default='', help='false_alarms.py seeds to examine too (comma-separated)')
    args = parser.parse_args()
    import robustness
    from aeropend_core.io.recording import from_columns
    from aeropend_core.model.parameters import DEFAULT_PARAMETERS
    from aeropend_core.sim.excitation import lhc_schedule
    from aeropend_core.sim.noise import MeasurementNoise
    from aeropend_core.sim.simulate import simulate
    lag = 0.15 * args.factor
    for seed in (int(s) for s in args.seeds.split(',') if s):
        top = robustness.DEFAULT_MAX_DUTY
        duty = lhc_schedule(robustness.DURATION, duty_range=(0.0, top), duty_cap=top,
                            seed=robustness.SEED_BASE + seed).duty(duration=robustness.DURATION)
        run = simulate(duty, DEFAULT_PARAMETERS, {'thrust_lag': {'time_constant': lag}},
                       noise=MeasurementNoise(args.psnr, True), seed=robustness.SEED_BASE + 500 + seed)
        describe(f'thrust lag {lag * 1e3:.2f} ms, {args.psnr:g} dB, seed {seed}, chain known',
                 from_columns(run.columns(with_truth=False), source='lag_evidence'), fixed={'angle_filter': 0.0},
                 only='thrust_lag')
    if args.clean:
        import false_alarms
        for seed in (int(s) for s in args.clean.split(',') if s):
            recording, row = false_alarms.record(seed)
            describe(f'clean record {row}', recording)


if __name__ == '__main__':
    main()

"""Is a dead zone's threshold within its ± on a continuous input (issue 40 item 3, "never silently wrong")?

Two sets of records, each fitted told the true structure (``diagnose(..., effects=<the true effects>)``, no
search), the threshold_voltage (and the angle offset where true) against the truth:

* ``own``: aeropend's own simulator (``aeropend_core.sim.simulate``), a 40 s duty chirp 0.1 Hz -> 1 or 2.5 Hz
  around duty 0.27 +- 0.18 (as ``bench/chirp_on_own_rig.py``), a dead zone drawn U(0.3, 0.9) V, PSNR U(30, 60) dB,
  all drawn from the seed.
* ``second``: the second truth simulator's records (``bench/second_rig.py``'s seeds, mixed excitation: steps, PRBS
  and a chirp) that carry a dead zone (its hub voltage); seeds without one are skipped without being simulated.

Run:  nice -n 10 .venv/bin/python bench/dead_zone_sigma.py own --records 20 --seed-base 500 [--rows PATH.jsonl]
      nice -n 10 .venv/bin/python bench/dead_zone_sigma.py second --records 12 --seed-base 44000 [--rows ...]
      .venv/bin/python bench/dead_zone_sigma.py summarise ROWS.jsonl [...]
(20-90 s per record)
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

THRESHOLD = 'threshold_voltage'


def own_record(seed: int):
    """(recording, truth {parameter: value}, PSNR [dB], effects) of an own-simulator chirp record with a dead zone."""
    import numpy as np

    from aeropend_core.io.recording import from_columns
    from aeropend_core.model.parameters import DEFAULT_PARAMETERS as rig
    from aeropend_core.sim.noise import MeasurementNoise
    from aeropend_core.sim.simulate import simulate
    rng = np.random.default_rng(seed + 104729)
    top = float(rng.choice([1.0, 2.5]))
    psnr_db = float(rng.uniform(30.0, 60.0))
    threshold = float(rng.uniform(0.3, 0.9))
    time_s = np.arange(int(40 * 490)) / 490.0
    duty = np.clip(0.27 + 0.18 * np.sin(2 * np.pi * (0.1 * time_s + (top - 0.1) / 80 * time_s ** 2)), 0.0, 0.6)
    duty[:245] = 0.0
    trajectory = simulate(duty, rig, effects={'dead_zone': threshold}, noise=MeasurementNoise(psnr_db, True),
                          seed=seed)
    truth = {name: getattr(rig, name) for name in ('gravity_stiffness', 'damping', 'thrust_gain',
                                                   'armature_resistance')}
    truth[THRESHOLD] = threshold
    return (from_columns(trajectory.columns(with_truth=False), source=f'own chirp seed {seed}'), truth, psnr_db,
            ['dead_zone'], f'chirp 0.1-{top:g} Hz')


def second_effects(seed: int) -> list[str]:
    """The second-rig effects seed `seed` carries (as bench/second_rig.py's ``record`` draws them)."""
    import numpy as np

    from aeropend_core.testing import second_rig
    if seed % 4 == 0:
        return []
    rng = np.random.default_rng(seed + 7919)
    effects: list[str] = []
    while not effects:
        effects = [name for name in second_rig.EFFECT_RANGES if rng.random() < 0.3]
    return effects


def fit_row(kind: str, seed: int) -> dict:
    from threadpoolctl import threadpool_limits

    from aeropend_core.diagnosis.diagnose import diagnose
    from aeropend_core.errors import AeropendError
    if kind == 'own':
        recording, truth, psnr_db, effects, note = own_record(seed)
    else:
        import second_rig as bench_second
        kinds = bench_second._effects_of_kind()
        recording, rig_record = bench_second.record(seed)
        effects = sorted({kinds[k][0] for k in rig_record.truth if k in kinds})
        truth = {name: value for name, value in rig_record.truth.items() if name in bench_second.NOMINAL}
        truth.update({kinds[k][1]: value for k, value in rig_record.truth.items() if k in kinds})
        psnr_db, note = rig_record.psnr_db, 'mixed'
    started = time.perf_counter()
    row = {'kind': kind, 'seed': seed, 'psnr_db': round(psnr_db, 1), 'effects': effects, 'note': note,
           'truth': truth}
    try:
        with threadpool_limits(1):
            told = diagnose(recording, effects=tuple(effects), candidates=(), drift=False, discovery=False)
    except AeropendError as error:
        row.update(refused=str(error)[:300], seconds=round(time.perf_counter() - started, 1))
        return row
    values, errors = told.reported_parameters(told.current), told.reported_errors(told.current)
    row['estimates'] = {name: values.get(name) for name in truth}
    row['sigmas'] = {name: errors.get(name) for name in truth}
    row['z'] = {name: ((values[name] - value) / errors[name]
                       if values.get(name) is not None and errors.get(name) and math.isfinite(errors[name])
                       and errors[name] > 0 else None) for name, value in truth.items()}
    profile = told.current.fit.extra.get('threshold_profile', {})
    before = dict(errors)
    before.update({name: value for name, value in profile.get('conditional_errors', {}).items()
                   if name != 'armature_resistance' or told.prepared.motor is None})
    row['sigmas_before'] = {name: before.get(name) for name in truth}
    row['z_before'] = {name: ((values[name] - value) / before[name]
                              if values.get(name) is not None and before.get(name) and math.isfinite(before[name])
                              and before[name] > 0 else None) for name, value in truth.items()}
    row['profile'] = {'interval': profile.get('interval'), 'refits': profile.get('refits')}
    row['seconds'] = round(time.perf_counter() - started, 1)
    return row


def med(values: list[float]) -> str:
    return f'{values[len(values) // 2]:.3g}' if values else '-'


def summarise(rows: list[dict]) -> list[str]:
    """Markdown table: per set and parameter, coverage with the sigma before (the level-spacing rule, threshold
    held) -> after (the profile), the median sigmas and the median absolute error."""
    lines = ['| set | parameter | records | within 1 sigma before -> after | within 2 sigma before -> after '
             '| median sigma before -> after | median abs error |', '| --- | --- | --- | --- | --- | --- | --- |']
    for kind in sorted({row['kind'] for row in rows}):
        fitted = [row for row in rows if row['kind'] == kind and 'z' in row]
        names = sorted({name for row in fitted for name in row['z']})
        for name in names:
            share = {}
            for key in ('z_before', 'z'):
                zs = [row[key][name] for row in fitted if name in row['z']]
                n = len(zs)
                share[key] = [100 * sum(1 for z in zs if z is not None and abs(z) <= k) / n for k in (1, 2)]
            sig = {key: sorted(row[key][name] for row in fitted if row[key].get(name) is not None)
                   for key in ('sigmas_before', 'sigmas')}
            err = sorted(abs(row['estimates'][name] - row['truth'][name]) for row in fitted
                         if row['estimates'].get(name) is not None)
            lines.append(f'| {kind} | {name} | {n} | {share["z_before"][0]:.0f} % -> {share["z"][0]:.0f} % '
                         f'| {share["z_before"][1]:.0f} % -> {share["z"][1]:.0f} % '
                         f'| {med(sig["sigmas_before"])} -> {med(sig["sigmas"])} | {med(err)} |')
        refused = sum(1 for row in rows if row['kind'] == kind and 'refused' in row)
        if refused:
            lines.append(f'| {kind} | (refused by the data-quality gate) | {refused} | | | | |')
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('kind', choices=('own', 'second', 'summarise'))
    parser.add_argument('paths', nargs='*', help='summarise: JSONL files written by --rows')
    parser.add_argument('--records', type=int, default=10, help='records to fit (second: with a dead zone)')
    parser.add_argument('--seed-base', type=int, default=500)
    parser.add_argument('--rows', metavar='PATH', default=None, help='append one JSON line per record here')
    args = parser.parse_args()
    if args.kind == 'summarise':
        if not args.paths:
            parser.error('summarise needs JSONL paths')
        rows = [json.loads(line) for path in args.paths for line in Path(path).read_text().splitlines() if line]
        print('\n'.join(summarise(rows)))
        return
    if args.records < 1 or args.seed_base < 0:
        parser.error('--records must be at least 1 and --seed-base at least 0')
    rows, seed = [], args.seed_base
    while len(rows) < args.records:
        if args.kind == 'second' and 'hub_voltage' not in second_effects(seed):
            seed += 1
            continue
        row = fit_row(args.kind, seed)
        rows.append(row)
        seed += 1
        if 'refused' in row:
            print(f'{row["seed"]} REFUSED {row["refused"][:120]}', flush=True)
        else:
            print(f'{row["seed"]} {row["psnr_db"]} dB {row["note"]} {",".join(row["effects"])}: ' + '; '.join(
                f'{name} {row["estimates"][name]:.4g} +- {row["sigmas_before"][name]:.2g} -> {row["sigmas"][name]:.2g} '
                f'(truth {row["truth"][name]:.4g}, z {row["z_before"][name]:+.1f} -> {row["z"][name]:+.1f})'
                for name in row['z'] if row['z'][name] is not None)
                + f' | {row["seconds"]} s', flush=True)
        if args.rows:
            with open(args.rows, 'a', encoding='utf-8') as handle:
                handle.write(json.dumps(row) + '\n')
    print('\n'.join(summarise(rows)))


if __name__ == '__main__':
    main()

"""Does the experiment loop decide confounded cases? (issue #26, second pass)

Four parts, each writing JSON to bench/results/2026-11-27-s8-loop2/ (the README there is written from them):

``loop``
    angle_offset vs cable_torque. The first record has no rests at the bottom (Latin-hypercube duty steps 0.35-0.7,
    the rod between ~25 and ~60 deg, 40 s, 40 dB) with one of the two effects hidden: the offset is then seen only
    through the curve's shape, like the cable spring (at small angles with rests the offset is pinned by the rests
    and a cable spring is absorbed by the gravity term: no confounding, README); the core loop of ``aeropend run
    --until-decided`` (:func:`aeropend_core.diagnosis.experiment_loop.until_decided`) then designs, plays on the
    in-process simulator and diagnoses all records together, within the loop's default limits (duty <= 0.7, every
    model's predicted angle < 80 deg, 3 runs). Counted per truth: decided correctly / wrongly / still confounded,
    rounds and seconds used. The simulator's noise is the stream's (fixed full-scale peaks, as a rig's ADC and the
    simulator node: the same absolute noise in every record).
``clean``
    the same loop on the clean simulator: must stay "nothing missing".
``lagfilter``
    thrust_lag vs angle_filter at 9, 15, 20 ms, both models at the simulator's own parameters: the predicted
    separation (what neither can absorb by refitting) of square waves of several mean duties, amplitudes and
    frequencies, and of the design's best schedule; the time each needs to decide at 30, 40 and 50 dB.
``joint``
    two 30 s records diagnosed jointly vs one 60 s record (the same samples), at 30 and 50 dB.

    nice -n 10 python bench/experiment_decide.py --part lagfilter
    nice -n 10 python bench/experiment_decide.py --part loop --seeds 8
"""
from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np

from aeropend_core.diagnosis.experiment_design import (DECISIVE_EVIDENCE, Block, CompetingModel, DutySchedule,
                                                       design_experiment, predict_separation)
from aeropend_core.diagnosis.experiment_loop import LoopBudget, Played, until_decided
from aeropend_core.io.recording import from_columns
from aeropend_core.model.parameters import DEFAULT_PARAMETERS as P
from aeropend_core.model.parameters import SAMPLE_TIME
from aeropend_core.present.verdict_text import verdict_of
from aeropend_core.present.json_output import finite_json
from aeropend_core.sim.excitation import lhc_schedule
from aeropend_core.sim.noise import FULL_SCALE, MeasurementNoise, sigma_for_psnr
from aeropend_core.sim.simulate import RigSimulator

OUT = Path(__file__).resolve().parent / 'results' / '2026-11-27-s8-loop2'
#: The angle's noise RMS [rad] of a stream at each PSNR (full-scale peak pi/2, as the simulator node and a rig).
NOISE = {db: sigma_for_psnr(FULL_SCALE['angle'], db) for db in (30.0, 40.0, 50.0)}


def stream_record(duty: np.ndarray, truth: dict, psnr: float, seed: int, source: str, quantise: bool = True):
    """A record of `duty` on the simulator with `truth` hidden, the stream's noise (full-scale peaks) and the ADC
    (the rig's 10-bit angle and current counts; `quantise` False: a finer sensor, the noise alone)."""
    simulator = RigSimulator(effects=truth, noise=MeasurementNoise(psnr, quantise), seed=seed)
    return from_columns(simulator.run(np.asarray(duty, dtype=float)).columns(with_truth=False), source=source)


# ------------------------------------------------------------------------------------------------ lag vs filter
def true_model(effect: str, values: dict) -> CompetingModel:
    """nominal + `effect` at the simulator's own parameters (1 % standard errors)."""
    parameters = {'gravity_stiffness': P.gravity_stiffness, 'damping': P.damping, 'thrust_gain': P.thrust_gain,
                  'armature_resistance': 0.0, **values}
    free = ('gravity_stiffness', 'damping', 'thrust_gain', *values)
    errors = np.array([0.01 * abs(parameters[n]) for n in free])
    return CompetingModel((effect,), parameters, free, np.diag(errors ** 2), True, f'nominal + {effect}')


def seconds_to_decide(separation_rad: float, samples: int, duration: float, noise_rms: float) -> float:
    """Time [s] for sum((separation / noise)^2) to reach DECISIVE_EVIDENCE, repeating a schedule of `duration` s."""
    evidence = (separation_rad / noise_rms) ** 2 * samples
    return duration * DECISIVE_EVIDENCE / evidence if evidence > 0 else math.inf


def lagfilter(args) -> dict:
    rows = []
    duration = 30.0
    for delay in (0.009, 0.015, 0.020):
        models = [true_model('thrust_lag', {'time_constant': delay}), true_model('angle_filter',
                                                                                 {'filter_delay': delay})]
        for mean in (0.2, 0.35, 0.5):
            for share in (0.5, 1.0):
                amplitude = share * min(mean, 0.7 - mean)
                for hz in (0.5, 1.0, 2.0, 4.0):
                    blocks = (Block('rest', 1.0), Block('square', duration - 1.0, mean, amplitude, hz, hz))
                    duty = DutySchedule(blocks).duty()
                    started = time.process_time()
                    score = predict_separation(models, duty, 1.0, draws=0)
                    simulated = RigSimulator(effects={'thrust_lag': delay}).run(duty)
                    rate = np.gradient(simulated.truth['angle'], SAMPLE_TIME)
                    samples = len(duty)
                    row = {'delay_s': delay, 'mean_duty': mean, 'amplitude_duty': amplitude, 'hz': hz,
                           'separation_rad': score['separation'], 'max_angle_deg': math.degrees(score['max_angle']),
                           'angle_rms_deg': math.degrees(float(np.std(simulated.truth['angle']))),
                           'rate_rms_rad_s': float(np.sqrt(np.mean(rate ** 2))),
                           'seconds_to_decide': {f'{db:g}': seconds_to_decide(score['separation'], samples,
                                                                              duration, sigma)
                                                 for db, sigma in NOISE.items()},
                           'cpu_seconds': time.process_time() - started}
                    rows.append(row)
                    print(json.dumps({k: row[k] for k in ('delay_s', 'mean_duty', 'amplitude_duty', 'hz',
                                                          'separation_rad', 'max_angle_deg', 'seconds_to_decide')}),
                          flush=True)
        started = time.process_time()
        design = design_experiment(models, NOISE[40.0], duration=duration, candidates=args.candidates,
                                   refinements=args.refinements, seed=int(delay * 1e3))
        rows.append({'delay_s': delay, 'design': [b.text() for b in design.schedule.blocks],
                     'separation_rad': design.separation * NOISE[40.0],
                     'separation_fitted_rad': design.separation_fitted * NOISE[40.0],
                     'max_angle_deg': math.degrees(design.max_angle),
                     'seconds_to_decide': {f'{db:g}': seconds_to_decide(design.separation * NOISE[40.0],
                                                                        design.samples, duration, sigma)
                                           for db, sigma in NOISE.items()},
                     'description': design.describe(), 'cpu_seconds': time.process_time() - started})
        print(json.dumps(rows[-1]), flush=True)
    return {'rows': rows, 'noise_rms_rad': {f'{db:g}': s for db, s in NOISE.items()}, 'duration_s': duration}


# ------------------------------------------------------------------------------------------------ the loop
#: The first record: duty steps in this range (no rests at the bottom), this long [s].
FIRST_DUTY = (0.35, 0.7)
FIRST_SECONDS = 40.0


def loop_case(truth: dict, seed: int, args, first_duty=FIRST_DUTY) -> dict:
    """One run of the core loop from a small-angle first record, played on the in-process simulator."""
    started = time.process_time()
    wall = time.perf_counter()

    def play(design, schedule) -> Played:
        if design is None:
            duty = lhc_schedule(FIRST_SECONDS, duty_range=first_duty, duty_cap=first_duty[1],
                                seed=seed).duty(duration=FIRST_SECONDS)
            played = f'latin hypercube, duty {first_duty[0]:g}-{first_duty[1]:g}, seed {seed}'
        else:
            duty = design.schedule.duty()
            played = '; '.join(b.text() for b in design.schedule.blocks)
        number = play.count = getattr(play, 'count', 0) + 1
        record = stream_record(duty, truth, args.psnr, seed + 100 * number, f'round {number}',
                               not getattr(args, 'no_quantise', False))
        return Played(record, f'round {number}', played, len(duty) * SAMPLE_TIME)

    budget = LoopBudget(max_runs=args.max_runs, max_seconds=args.max_seconds, design_seconds=args.design_seconds)
    outcome = until_decided(play, budget, {'drift': False}, seed=seed,
                            write_schedule=lambda number, design: f'in memory, round {number}',
                            design_options={'candidates': args.candidates, 'refinements': args.refinements,
                                            'original_duty_limit': first_duty[1]})
    rounds = []
    measured = {}
    from aeropend_core.diagnosis.experiment_design import measured_separation
    if getattr(args, 'measure', False):     # the separation measured on each played designed record
        for before, after in zip(outcome.rounds[:-1], outcome.rounds[1:]):
            design = before.design
            sets = [m.effects for m in design.models]
            measured[after.number] = {
                'noisy': measured_separation(after.played.recording, sets, design.noise_rms),
                'noise_free': measured_separation(from_columns(RigSimulator(effects=truth).run(
                    design.schedule.duty()).columns(with_truth=False), source='noise-free'), sets, design.noise_rms),
                'models': [list(e) for e in sets]}
    for r in outcome.rounds:
        entry = {'round': r.number, 'played': r.played.played, 'verdict': r.diagnosis.verdict,
                 'message': verdict_of(r.diagnosis), 'pinned': [f.effect for f in r.diagnosis.found
                                                            if not f.confounded_with],
                 'confounded': [[f.effect, *f.confounded_with] for f in r.diagnosis.found if f.confounded_with],
                 'sizes': {f.effect: {k: [v, f.standard_errors.get(k)] for k, v in f.parameters.items()}
                           for f in r.diagnosis.found},
                 'max_angle_deg': math.degrees(float(np.max(np.abs(r.played.recording.signals['angle'])))),
                 'diagnosis_seconds': r.diagnosis_seconds}
        if r.number in measured:
            entry['measured_separation'] = measured[r.number]
        if r.design is not None:
            entry.update(predicted_separation=r.design.separation, original_separation=r.design.baseline_separation,
                         predicted_separation_heldout=r.design.separation_heldout,
                         predicted_separation_train=r.design.separation_train,
                         predicted_separation_fitted=r.design.separation_fitted,
                         seconds_to_decide=r.design.seconds_to_decide, design_seconds=r.design_seconds,
                         repeats=r.design.repeats, played_next=bool(r.next_schedule),
                         predicted_max_angle_deg=math.degrees(r.design.max_angle))
        rounds.append(entry)
    last_design = outcome.rounds[-1].design if outcome.rounds else None
    if getattr(args, 'measure', False) and last_design is not None and outcome.verdict != 'decided' \
            and not outcome.rounds[-1].next_schedule:
        # the design the loop did not play (cannot decide within the budget): its separation measured noise-free
        sets = [m.effects for m in last_design.models]
        rounds[-1]['measured_separation_unplayed'] = {
            'noise_free': measured_separation(from_columns(RigSimulator(effects=truth).run(
                last_design.schedule.duty()).columns(with_truth=False), source='noise-free'), sets,
                last_design.noise_rms), 'models': [list(e) for e in sets]}
    final = outcome.decision
    wanted = set(truth)
    pinned = {f.effect for f in final.found if not f.confounded_with} if final is not None else set()
    if final is None:
        result = 'no decision'
    elif outcome.verdict == 'cannot_decide_within_budget':
        result = 'cannot within budget'
    elif final.verdict == 'confounded':
        result = 'still confounded'
    elif not wanted:
        result = 'correct' if final.verdict == 'nothing_missing' else 'wrong'
    elif final.verdict == 'nothing_missing':
        result = 'missed'       # nothing named: not a wrong name (the first record alone misses a small effect)
    else:
        result = 'correct' if final.verdict == 'effect_found' and pinned == wanted else 'wrong'
    return {'truth': truth, 'seed': seed, 'first_verdict': rounds[0]['verdict'] if rounds else None,
            'final_verdict': final.verdict if final is not None else None, 'result': result,
            'runs': len(outcome.rounds), 'excitation_seconds': outcome.excitation_seconds, 'ending': outcome.ending,
            'loop_verdict': outcome.verdict, 'needed_seconds': outcome.needed_seconds,
            'needed_noise_rms_rad': outcome.needed_noise_rms, 'budget_seconds': args.max_seconds,
            'rounds': rounds, 'cpu_seconds': time.process_time() - started, 'wall_seconds': time.perf_counter() - wall}


TRUTHS = {'offset': {'angle_offset': 0.01}, 'cable': {'cable_torque': 30.0}, 'clean': {},
          'lag': {'thrust_lag': 0.02}, 'filter': {'angle_filter': 0.02}}
#: The lag/filter pair starts from the usual Latin hypercube over duty 0-0.7.
FIRST_DUTY_OF = {'lag': (0.0, 0.7), 'filter': (0.0, 0.7)}


def loop(args, names) -> dict:
    rows = []
    stem = f'loop_{"_".join(names)}' if args.size is None else f'loop_{"_".join(names)}_{args.size:g}'
    path = OUT / f'{stem}{args.tag}.json'
    seeds = ([int(v) for v in args.seed_list.split(',')] if args.seed_list
             else [args.first_seed + k for k in range(args.seeds)])
    for seed in seeds:
        for name in names:
            truth = {effect: (args.size if args.size is not None else value) for effect, value in TRUTHS[name].items()}
            row = loop_case(truth, seed, args, FIRST_DUTY_OF.get(name, FIRST_DUTY))
            row['case'] = name
            rows.append(row)
            print(json.dumps({key: row[key] for key in ('case', 'seed', 'first_verdict', 'final_verdict', 'result',
                                                        'runs', 'excitation_seconds', 'cpu_seconds')}), flush=True)
            path.write_text(json.dumps(finite_json({'rows': rows, 'settings': vars(args)}), indent=2) + '\n')
    return {'rows': rows}


# ------------------------------------------------------------------------------------------------ joint vs one
def joint(args) -> dict:
    from aeropend_core.diagnosis.diagnose import diagnose
    from aeropend_core.diagnosis.joint import diagnose_joint
    rows = []
    truth = {'coulomb_friction': 4.0}
    for psnr in (30.0, 50.0):
        for k in range(args.seeds):
            seed = args.first_seed + k
            duty = lhc_schedule(60.0, seed=seed).duty(duration=60.0)
            whole = stream_record(duty, truth, psnr, seed + 1, 'whole')
            halves = [whole.window(0.0, 30.0), whole.window(30.0, 61.0)]
            started = time.process_time()
            together = diagnose_joint(halves, drift=False)
            single = diagnose(whole, drift=False)
            name = 'friction_acceleration'

            def size(d):
                f = next((f for f in d.found if f.effect == 'coulomb_friction'), None)
                return (f.parameters[name], f.standard_errors[name]) if f else (math.nan, math.nan)
            (a, sa), (b, sb) = size(together), size(single)
            rows.append({'psnr_db': psnr, 'seed': seed, 'joint_verdict': together.verdict,
                         'single_verdict': single.verdict, 'joint': [a, sa], 'single': [b, sb],
                         'difference_in_sigma': abs(a - b) / math.hypot(sa, sb) if sa and sb else math.nan,
                         'cpu_seconds': time.process_time() - started})
            print(json.dumps(rows[-1]), flush=True)
            (OUT / 'joint.json').write_text(json.dumps(finite_json({'rows': rows, 'truth': truth}), indent=2) + '\n')
    return {'rows': rows, 'truth': truth}


def summary() -> str:
    """Markdown tables of the JSON files written so far."""
    lines = ['| case | seeds | first record confounded | of those: decided correctly | decided wrongly | still '
             'confounded | runs (mean) | excitation s (mean) | CPU s per case (mean) | first record not confounded |',
             '|' + '---|' * 10]
    for path in sorted(OUT.glob('loop_*.json')):
        rows = json.loads(path.read_text())['rows']
        truth = rows[0]['truth']
        confounded = [r for r in rows if r['first_verdict'] == 'confounded']
        count = {k: sum(r['result'] == k for r in confounded) for k in ('correct', 'wrong', 'still confounded')}
        others = ', '.join(f'{v}: {sum(r["first_verdict"] == v and r["result"] == "correct" for r in rows)} right '
                           f'of {sum(r["first_verdict"] == v for r in rows)}'
                           for v in sorted({r['first_verdict'] for r in rows} - {'confounded'}))

        def mean(key, confounded=confounded):
            return float(np.mean([r[key] for r in confounded])) if confounded else math.nan
        lines.append(f'| {truth or "clean"} | {len(rows)} | {len(confounded)} | {count["correct"]} | {count["wrong"]} '
                     f'| {count["still confounded"]} | {mean("runs"):.2f} | {mean("excitation_seconds"):.0f} | '
                     f'{mean("cpu_seconds"):.0f} | {others} |')
    path = OUT / 'joint.json'
    if path.exists():
        lines += ['', '| PSNR dB | seed | one 60 s record | two 30 s records jointly | Fc one [rad/s^2] | Fc joint | '
                  'difference / sigma |', '|' + '---|' * 7]
        for r in json.loads(path.read_text())['rows']:
            lines.append(f'| {r["psnr_db"]:g} | {r["seed"]} | {r["single_verdict"]} | {r["joint_verdict"]} | '
                         f'{r["single"][0]:.3f} +- {r["single"][1]:.3f} | {r["joint"][0]:.3f} +- {r["joint"][1]:.3f} | '
                         f'{r["difference_in_sigma"]:.2f} |')
    return '\n'.join(lines)


def table(folder: Path) -> str:
    """Markdown table of the loop runs (``loop_*.json``) in `folder`, one row per loop (the results folders'
    ``table.py``)."""
    lines = ['| truth | PSNR dB | budget | seed | first record | loop result | runs | s played | estimate +- sigma | '
             '(estimate - truth) / sigma | CPU s |', '|---|---|---|---|---|---|---|---|---|---|---|']
    for path in sorted(Path(folder).glob('loop_*.json')):
        data = json.loads(path.read_text())
        psnr = f"{data['settings']['psnr']:g}" + (' (no ADC)' if data['settings'].get('no_quantise') else '')
        budget = f"{data['settings']['max_runs']} runs, {data['settings']['max_seconds']:g} s"
        for row in data['rows']:
            truth = row['truth']
            name, size = next(iter(truth.items())) if truth else ('clean', math.nan)
            sizes = row['rounds'][-1].get('sizes', {}) if row['rounds'] else {}
            estimate = ''
            z = ''
            for effect, parameters in sizes.items():
                for parameter, (value, sigma) in parameters.items():
                    estimate += f'{effect} {value * 1e3:.2f} +- {sigma * 1e3:.2f} ms ' if parameter in (
                        'time_constant', 'filter_delay') else f'{effect} {parameter} {value:.4g} +- {sigma:.2g} '
                    if effect == name and sigma > 0:
                        z = f'{(value - size) / sigma:+.2f}'
            label = ('clean' if not truth else f'{name} {size * 1e3:.0f} ms' if name in ('thrust_lag', 'angle_filter')
                     else f'{name} {size:g}')
            # files written before the bench said 'missed' counted a first record that names nothing as 'wrong'
            result = 'missed' if row['result'] == 'wrong' and row['final_verdict'] == 'nothing_missing' \
                else row['result']
            lines.append(f'| {label} | {psnr} | {budget} | {row["seed"]} | {row["first_verdict"]} | {result} | '
                         f'{row["runs"]} | {row["excitation_seconds"]:.0f} | {estimate.strip() or "-"} | {z or "-"} | '
                         f'{row["cpu_seconds"]:.0f} |')
    return '\n'.join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--part', choices=['loop', 'clean', 'lagfilter', 'joint', 'summary'], required=True)
    parser.add_argument('--cases', default='offset,cable', help='loop: which truths (offset, cable, lag)')
    parser.add_argument('--seeds', type=int, default=8)
    parser.add_argument('--size', type=float, default=None, help='loop: hidden effect size (SI)')
    parser.add_argument('--first-seed', type=int, default=26000)
    parser.add_argument('--seed-list', default='', help='loop: these seeds (comma-separated) instead of --seeds')
    parser.add_argument('--psnr', type=float, default=40.0)
    parser.add_argument('--candidates', type=int, default=30)
    parser.add_argument('--refinements', type=int, default=15)
    parser.add_argument('--design-seconds', type=float, default=30.0)
    parser.add_argument('--no-quantise', action='store_true',
                        help='loop: no 10-bit ADC counts (a finer angle sensor than the rig\'s, the noise alone)')
    parser.add_argument('--max-runs', type=int, default=3)
    parser.add_argument('--max-seconds', type=float, default=300.0, help='loop: excitation budget over all runs [s]')
    parser.add_argument('--measure', action='store_true',
                        help='loop: also measure the separation on each played designed record (both models refitted)')
    parser.add_argument('--out', default=None,
                        help='folder of the JSON results (default bench/results/2026-11-27-s8-loop2)')
    parser.add_argument('--tag', default='', help='loop: suffix of the JSON file name (e.g. _before)')
    args = parser.parse_args()
    global OUT
    if args.out is not None:
        OUT = Path(args.out)
    OUT.mkdir(parents=True, exist_ok=True)
    if args.part == 'summary':
        print(summary())
    elif args.part == 'lagfilter':
        result = lagfilter(args)
        (OUT / 'lagfilter.json').write_text(json.dumps(finite_json({**result, 'settings': vars(args)}),
                                                       indent=2) + '\n')
    elif args.part == 'joint':
        joint(args)
    else:
        loop(args, ['clean'] if args.part == 'clean' else args.cases.split(','))


if __name__ == '__main__':
    main()

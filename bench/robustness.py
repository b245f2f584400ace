"""Noise-robustness of the missing-physics loop: how often is a hidden effect named correctly, vs PSNR and size.

For every effect in the catalog (read at run time, so a newly registered effect is included) one effect is hidden
in simulated data and :func:`aeropend_core.diagnosis.diagnose.diagnose` is asked what is missing:

* (a) rate vs PSNR at the catalog's typical magnitude, PSNR 60/50/40/30/20 dB;
* (b) rate vs magnitude at 40 dB, magnitudes as multiples of the typical value;
* the clean case (nothing hidden): false-alarm rate vs PSNR.

Data per run (as bench/diagnosis_table.py and tests/test_diagnose.py): 60 s of Latin-hypercube duty steps (LHC,
duty up to 0.7; for cable_torque up to the duty that holds the rod at 75 deg, the large-angle experiment the tool
recommends for it), simulated with the full model, Gaussian noise at the PSNR on Va, Ia and the angle plus 10-bit
quantisation of angle and current; only the measured columns reach the diagnosis. Seed k of a point uses the LHC
schedule seed ``SEED_BASE + k`` and the noise seed ``SEED_BASE + 500 + k`` -- the same schedules at every point
(paired comparisons along a curve), none shared with the tests or the diagnosis table.

Every run is classified:

``correct``            verdict effect_found naming the hidden effect
``confounded_truth``   verdict confounded, the hidden effect among the named ones (honest uncertainty, not correct)
``confounded_other``   verdict confounded, the hidden effect not among them
``missed``             verdict nothing_missing
``wrong``              verdict effect_found naming another effect (or more than the hidden one)
``unexplained``        verdict unexplained (model off, no catalog effect helps)
``drift``              verdict drift (a nominal parameter trends in time)
``crash``              the diagnosis raised (the traceback is kept in the JSON)

For the clean case ``missed`` (nothing_missing) is the right answer; every other outcome is a false alarm.

**The measurement chain.** By default the diagnosis is not told anything about the angle sensor's chain: the
``angle_filter`` stays a candidate (the *unknown-chain* rows). ``--known-chain`` adds rows (b) and the clean points
once more with the chain KNOWN: the diagnosis gets the simulated rig's angle-filter delay as a fixed hardware value,
``fixed={'angle_filter': delay}``, exactly what ``aeropend diagnose --fix angle_filter=DELAY`` or ``--calibration``
pass to :func:`diagnose` (delay 0 s: "no filter on the angle", as a calibration file stating
``angle_filter_delay: 0.0``). ``--chain-filter DELAY`` gives every simulated record (clean ones too) an angle filter
of that delay [s] on top of the hidden effect (the rig's RC filter: 0.0141); the unknown-chain rows are then the
rig read through a filter nobody stated. With a chain filter, or with the chain known, ``angle_filter`` is not a
hidden effect of its own (it is part of the chain). Rows with the chain known are labelled ``chain known`` in
robustness.md and carry ``"chain": "known"`` in the JSON.

Run:  .venv/bin/python bench/robustness.py [--quick] [--seeds N] [--out DIR] [--json PATH] [--effects A B ...]
      [--varied] [--known-chain] [--chain-filter DELAY]
Time on the 2-core machine: default (260 diagnoses) 5.3 min idle, 10-14 min when busy; --quick (66) 1 min idle,
2 min busy. Writes OUT/robustness.json (or --json PATH), OUT/robustness.md, OUT/rate_vs_psnr.png and
OUT/rate_vs_magnitude.png; exit status 1 if any diagnosis crashed (its traceback is in the JSON).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import time
import traceback
from datetime import datetime, timezone
from multiprocessing import get_context
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from aeropend_core.model.effects import CATALOG, get_effect  # noqa: E402
from aeropend_core.model.parameters import DEFAULT_PARAMETERS  # noqa: E402

#: PSNR points [dB] of curve (a) and the PSNR of curve (b).
PSNRS = (60.0, 50.0, 40.0, 30.0, 20.0)
MAGNITUDE_PSNR = 40.0
#: Magnitudes of curve (b), as multiples of the catalog's typical value.
MAGNITUDES = (1 / 16, 1 / 8, 1 / 4, 1 / 2, 1.0, 2.0)
QUICK_PSNRS = (50.0, 40.0, 30.0)
QUICK_MAGNITUDES = (1 / 16, 1 / 4, 1.0)
SEEDS, QUICK_SEEDS = 4, 2
SEED_BASE = 7100
DURATION = 60.0
#: Largest duty of the LHC steps (the rod settles near 65 deg there with the default parameters).
DEFAULT_MAX_DUTY = 0.7
#: Effects for which the diagnosis itself advises "excite larger angles" (the cable: separable from gravity only
#: there) get the experiment it recommends: the highest step holds the rod at this angle [rad], as an operator
#: following the advice (70-85 deg) would set it, with room for the ~10 % overshoot of a large step. (A fixed duty,
#: e.g. 0.9 as in bench/diagnosis_table.py, throws the rod over the top when the cable is weak.)
LARGE_ANGLE = math.radians(75.0)
#: A magnitude counts as reliably detected when at least this fraction of its seeds is correct.
RELIABLE = 0.75
#: An effect still reliably found at the smallest tested magnitude is tried at half of it, and so on, down to
#: this multiple of its typical value (so that every curve shows where detection fails).
SMALLEST_FACTOR = 1 / 256
#: The measurement chain as the diagnosis sees it: 'unknown' (angle_filter a candidate) or 'known' (held fixed).
UNKNOWN_CHAIN, KNOWN_CHAIN = 'unknown', 'known'
OUTCOMES = ('correct', 'confounded_truth', 'confounded_other', 'missed', 'wrong', 'unexplained', 'drift', 'crash')
CLEAN = 'none'
#: --varied: every nominal parameter moved by 20 % (as tests/test_diagnose.py), so that nothing leans on defaults.
VARIED_PARAMETERS = DEFAULT_PARAMETERS.scaled(
    armature_resistance=0.8, armature_inductance=1.2, back_emf_constant=1.2, torque_constant=1.2,
    motor_inertia=0.8, motor_friction=0.8, propeller_torque_coefficient=0.8, thrust_coefficient=0.8,
    gravity_stiffness=1.2, damping=0.8, lever_per_inertia=1.2)


def max_duty(effect: str, truth: dict[str, float] | None, parameters) -> float:
    """Largest duty of the LHC steps for a case: DEFAULT_MAX_DUTY, or the large-angle experiment (see LARGE_ANGLE)."""
    from aeropend_core.diagnosis.diagnose import excitation_advice
    from aeropend_core.model.effects import PENDULUM
    if truth is None or 'larger angles' not in excitation_advice(effect) or get_effect(effect).kind != PENDULUM:
        return DEFAULT_MAX_DUTY
    # thrust acceleration that holds the rod at LARGE_ANGLE against gravity and the effect (at rest)
    needed = parameters.gravity_stiffness * math.sin(LARGE_ANGLE) - float(
        get_effect(effect).function(LARGE_ANGLE, 0.0, **truth))

    def thrust_acceleration(duty: float) -> float:
        state = parameters.steady_state(parameters.voltage_from_duty(duty))
        return parameters.lever_per_inertia * state['thrust']

    low, high = DEFAULT_MAX_DUTY / 2, 1.0
    if thrust_acceleration(high) <= needed:
        return high
    for _ in range(40):
        middle = 0.5 * (low + high)
        low, high = (middle, high) if thrust_acceleration(middle) < needed else (low, middle)
    return round(low, 4)


def _worker_init() -> None:
    from threadpoolctl import threadpool_limits
    global _LIMITS
    _LIMITS = threadpool_limits(1)        # one BLAS thread per worker: 2 workers on 2 cores


def run_case(case: dict) -> dict:
    """Simulate one recording with `case['effect']` hidden at `case['factor']` x typical, diagnose, classify."""
    from aeropend_core.diagnosis.diagnose import diagnose
    from aeropend_core.sim.excitation import lhc_schedule
    from aeropend_core.sim.noise import MeasurementNoise
    from aeropend_core.io.recording import from_columns
    from aeropend_core.sim.simulate import simulate

    effect, factor, psnr, seed = case['effect'], case['factor'], case['psnr'], case['seed']
    parameters = VARIED_PARAMETERS if case.get('varied') else DEFAULT_PARAMETERS
    chain_delay = float(case.get('chain_filter', 0.0))     # the simulated rig's angle filter [s] (0: none)
    result = dict(case)
    truth = None
    simulated_effects = {}
    if effect != CLEAN:
        truth = {p.name: p.typical * factor for p in get_effect(effect).parameters}
        result['truth'] = truth
        simulated_effects[effect] = truth
    if chain_delay > 0.0:
        simulated_effects['angle_filter'] = {'filter_delay': chain_delay}
    # chain known: the simulated rig's filter delay as a fixed hardware value, as --fix / --calibration pass it
    known = case.get('chain', UNKNOWN_CHAIN) == KNOWN_CHAIN
    fixed = {'angle_filter': chain_delay} if known else None
    fixed_from = {'angle_filter': 'the simulated rig (bench --known-chain)'} if known else None
    started = time.perf_counter()
    try:
        top = result['max_duty'] = max_duty(effect, truth, parameters)
        schedule = lhc_schedule(DURATION, duty_range=(0.0, top), duty_cap=top, seed=SEED_BASE + seed)
        duty = schedule.duty(duration=DURATION)
        trajectory = simulate(duty, parameters, simulated_effects or None, noise=MeasurementNoise(psnr, True),
                              seed=SEED_BASE + 500 + seed)
        found = diagnose(from_columns(trajectory.columns(with_truth=False), source=f'robustness {case}'),
                         fixed=fixed, fixed_from=fixed_from)
    except Exception as error:   # a crash is an outcome to report, not a reason to stop the sweep
        result.update(outcome='crash', verdict='crash', named=[], error=f'{type(error).__name__}: {error}',
                      traceback=traceback.format_exc(), seconds=time.perf_counter() - started)
        return result
    named = []
    if found.verdict == 'effect_found':
        named = list(found.missing_effects)
    elif found.verdict == 'confounded':
        named = [n for f in found.found for n in [f.effect, *f.confounded_with] if n in CATALOG]
    result.update(verdict=found.verdict, named=named, noise_rms=found.noise_rms, fixed=dict(found.fixed),
                  excess_now=_excess(found.current.rms_error, found.noise_rms),
                  max_true_angle_deg=math.degrees(float(abs(trajectory.truth['angle']).max())),
                  seconds=time.perf_counter() - started)
    result['unstated'] = ['angle_filter'] if chain_delay > 0.0 and not known else []
    result['outcome'] = classify(effect, found.verdict, named, tuple(result['unstated']))
    if truth is not None:
        hidden = next((c for c in found.candidates if c.effect == effect), None)
        if hidden is not None and hidden.parameters:
            name = next(iter(truth))
            estimate = hidden.parameters.get(name, float('nan'))
            result['estimate'] = estimate
            result['relative_error'] = (estimate - truth[name]) / truth[name] if truth[name] else float('nan')
            result['hidden_significant'] = hidden.significant
            # the evidence behind the outcome (first round, against the current model): why a size is missed
            result['hidden_evidence'] = {'t': hidden.t_statistic, 'delta_bic': hidden.delta_bic,
                                         'dm': hidden.dm_statistic, 'share': hidden.share_removed,
                                         'gain_per_noise_variance': hidden.mse_gain / found.noise_rms ** 2}
            interval = hidden.comparison.fit.extra.get('threshold_interval') if hidden.comparison else None
            if interval is not None:      # a dead zone's threshold is known only between two input levels
                result['interval'] = list(interval)
                result['truth_in_interval'] = bool(interval[0] <= truth[name] <= interval[1])
    return result


def _excess(rms: float, noise: float) -> float:
    return math.sqrt(max(rms ** 2 - noise ** 2, 0.0))


def classify(effect: str, verdict: str, named: list[str], unstated: tuple[str, ...] = ()) -> str:
    """One of OUTCOMES for a diagnosis of data with `effect` hidden (CLEAN: nothing hidden).

    `unstated`: effects also in the record that the diagnosis was not told about (an angle filter of the simulated
    chain when the chain is unknown). Naming the hidden effect with or without them is correct (its estimate then
    absorbs theirs: see the error column); naming one of them instead, e.g. a confident thrust lag on a clean record
    read through a filter, is wrong.
    """
    truth = ([] if effect == CLEAN else [effect]) + list(unstated)
    if verdict == 'effect_found':
        hidden_named = effect != CLEAN and effect in named and set(named) <= set(truth)
        return 'correct' if hidden_named or (truth and sorted(named) == sorted(truth)) else 'wrong'
    if verdict == 'confounded':
        return 'confounded_truth' if any(name in named for name in truth) else 'confounded_other'
    if verdict == 'nothing_missing':
        return 'missed'
    if verdict in ('unexplained', 'drift'):
        return verdict
    return 'crash'


def build_cases(effects: list[str], psnrs, magnitudes, seeds: int, known_chain: bool = False,
                chain_filter: float = 0.0) -> list[dict]:
    """Every (effect, magnitude, PSNR, chain, seed) case; with `known_chain` curve (b) and the clean points again
    with the measurement chain known to the diagnosis (not for angle_filter itself, which is then part of it)."""
    points = []
    for effect in effects:
        for psnr in psnrs:
            points.append((effect, 1.0, psnr, UNKNOWN_CHAIN))
        for factor in magnitudes:
            if (effect, factor, MAGNITUDE_PSNR, UNKNOWN_CHAIN) not in points:
                points.append((effect, factor, MAGNITUDE_PSNR, UNKNOWN_CHAIN))
    for psnr in psnrs:
        points.append((CLEAN, 0.0, psnr, UNKNOWN_CHAIN))
    if known_chain:
        points += [(e, f, MAGNITUDE_PSNR, KNOWN_CHAIN) for e in effects if e != 'angle_filter' for f in magnitudes]
        points += [(CLEAN, 0.0, p, KNOWN_CHAIN) for p in psnrs]
    return [{'effect': e, 'factor': f, 'psnr': p, 'chain': c, 'chain_filter': chain_filter, 'seed': s}
            for e, f, p, c in points for s in range(1, seeds + 1)]


def summarise(runs: list[dict], effect: str, factor: float, psnr: float, chain: str = UNKNOWN_CHAIN) -> dict:
    selected = [r for r in runs if r['effect'] == effect and r['factor'] == factor and r['psnr'] == psnr
                and r.get('chain', UNKNOWN_CHAIN) == chain]
    counts = {o: sum(r['outcome'] == o for r in selected) for o in OUTCOMES}
    errors = [abs(r['relative_error']) for r in selected
              if r['outcome'] == 'correct' and math.isfinite(r.get('relative_error', float('nan')))]
    errors.sort()
    summary = {'effect': effect, 'factor': factor, 'psnr': psnr, 'chain': chain, 'runs': len(selected),
               'counts': counts,
               'correct_rate': counts['correct'] / len(selected) if selected else float('nan'),
               'median_abs_relative_error': errors[len(errors) // 2] if errors else None,
               'max_abs_relative_error': errors[-1] if errors else None,
               'over_horizontal': sum(r.get('max_true_angle_deg', 0.0) > 90.0 for r in selected)}
    intervals = [r['truth_in_interval'] for r in selected if r['outcome'] == 'correct' and 'truth_in_interval' in r]
    if intervals:
        summary['correct_with_truth_in_interval'] = sum(intervals)
    if effect != CLEAN:
        summary['value'] = {p.name: p.typical * factor for p in get_effect(effect).parameters}
    else:
        # a record read through a filter nobody stated is not clean: no false-alarm rate for it
        unstated = any(r.get('unstated') for r in selected)
        summary['false_alarm_rate'] = None if unstated or not selected else 1.0 - counts['missed'] / len(selected)
    return summary


def smallest_reliable(points: list[dict]) -> dict | None:
    """The smallest magnitude from which every larger tested one is correct in >= RELIABLE of its seeds."""
    points = sorted(points, key=lambda p: p['factor'])
    smallest = None
    for point in reversed(points):
        if point['correct_rate'] >= RELIABLE:
            smallest = point
        else:
            break
    return smallest


def _plain(value):
    """JSON-safe copy: NaN/inf -> None, numpy scalars -> float."""
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, (bool, int, str)) or value is None:
        return value
    value = float(value)
    return value if math.isfinite(value) else None


def _percent(value: float) -> str:
    return f'{value * 100:.0f}'


def markdown(report: dict) -> str:
    lines = [f'# Missing-physics loop: robustness ({report["date"]}, {report["machine"]})', '',
             f'{report["seeds"]} seeds per point, {report["duration_s"]:g} s LHC records, '
             f'{report["runs"]} diagnoses in {report["wall_seconds"]:.0f} s wall on {report["workers"]} workers'
             f'{" (--quick)" if report["quick"] else ""}'
             f'{", every nominal parameter moved 20 %" if report["varied_parameters"] else ""}. '
             'Counts per point: C correct, CT confounded incl. the '
             'truth, CO confounded without it, M missed (nothing_missing), W wrong name, U unexplained, X crash.', '']
    header = '| hidden effect | magnitude | PSNR dB | C | CT | CO | M | W | U | X | median abs error of estimate |'
    rule = '|---|---|---|---|---|---|---|---|---|---|---|'
    lines += ['## (a) vs PSNR at the typical magnitude', '', header, rule]
    for point in report['vs_psnr']:
        lines.append(_row(point))
    chain = report.get('measurement_chain', {})
    delay = chain.get('simulated_filter_delay_s', 0.0)
    through = f'; the simulated rig reads the angle through a {delay * 1e3:g} ms filter' if delay else ''
    lines += ['', f'## (b) vs magnitude at {MAGNITUDE_PSNR:g} dB, measurement chain unknown (angle_filter a '
              f'candidate{through})', '', header, rule]
    for point in report['vs_magnitude']:
        if point.get('chain', UNKNOWN_CHAIN) == UNKNOWN_CHAIN:
            lines.append(_row(point))
    if chain.get('known_rows'):
        held = f'the simulated rig\'s {delay * 1e3:g} ms' if delay else '0 s, no filter on the angle'
        lines += ['', f'## (c) vs magnitude at {MAGNITUDE_PSNR:g} dB, measurement chain KNOWN to the diagnosis '
                  f'(angle_filter held at {held}, as --fix angle_filter={delay:g} or a calibration file would give '
                  'it; NOT the unknown-chain case above)', '', header, rule]
        for point in report['vs_magnitude']:
            if point.get('chain') == KNOWN_CHAIN:
                lines.append(_row(point))
    lines += ['', '## Clean data (nothing hidden): false alarms vs PSNR', '',
              '| PSNR dB | chain | nothing_missing | effect_found | confounded | unexplained | crash | '
              'false-alarm rate |',
              '|---|---|---|---|---|---|---|---|']
    for point in report['clean']:
        c = point['counts']
        lines.append(f'| {point["psnr"]:g} | {point.get("chain", UNKNOWN_CHAIN)} | {c["missed"]} | '
                     f'{c["wrong"] + c["correct"]} | '
                     f'{c["confounded_truth"] + c["confounded_other"]} | {c["unexplained"]} | {c["crash"]} | '
                     + ('- (an unstated angle filter is in the record: missed, M, is the wrong answer here) |'
                        if point['false_alarm_rate'] is None else f'{_percent(point["false_alarm_rate"])} % |'))
    known = report.get('thresholds_known_chain', {})
    lines += ['', f'## Smallest reliably detected magnitude (correct in >= {RELIABLE:.0%} of seeds at it and at '
              f'every larger tested magnitude, {MAGNITUDE_PSNR:g} dB)', '',
              '| effect | parameter | typical | smallest reliable, chain unknown | as x typical |'
              + (' smallest reliable, chain KNOWN |' if known else ''),
              '|---|---|---|---|---|' + ('---|' if known else '')]

    def reached(entry: dict | None) -> str:
        if entry is None:
            return '-'
        if entry['factor'] is None:
            return 'not reached in the tested range'
        return f'{entry["value"]:.4g} {entry["unit"]}'

    for effect, entry in report['thresholds'].items():
        factor = '-' if entry['factor'] is None else f'{entry["factor"]:g}'
        lines.append(f'| {effect} | {entry["parameter"]} | {entry["typical"]:g} {entry["unit"]} | {reached(entry)} | '
                     f'{factor} |' + (f' {reached(known.get(effect))} |' if known else ''))
    return '\n'.join(lines) + '\n'


def _row(point: dict) -> str:
    c = point['counts']
    value = ', '.join(f'{v:.4g}' for v in point['value'].values())
    error = point['median_abs_relative_error']
    error_text = '-' if error is None else f'{error * 100:.1f} %'
    if 'correct_with_truth_in_interval' in point:
        error_text += f' (truth in the reported interval {point["correct_with_truth_in_interval"]}/{c["correct"]})'
    if point['over_horizontal']:
        error_text += f'; rod above horizontal in {point["over_horizontal"]}/{point["runs"]} runs'
    label = point['effect'] + (' (chain known)' if point.get('chain') == KNOWN_CHAIN else '')
    return (f'| {label} | {value} (x{point["factor"]:g}) | {point["psnr"]:g} | {c["correct"]} | '
            f'{c["confounded_truth"]} | {c["confounded_other"]} | {c["missed"]} | {c["wrong"]} | '
            f'{c["unexplained"]} | {c["crash"]} | {error_text} |')


def _finish(fig, axes, used: int, title: str, path: Path) -> str:
    """Blank the unused panels, one legend for the figure (each label once), title, save as PNG; returns the path."""
    import matplotlib.pyplot as plt
    for extra in list(axes.flat)[used:]:
        extra.axis('off')
    legend: dict[str, object] = {}
    for ax in axes.flat:
        for handle, label in zip(*ax.get_legend_handles_labels()):
            legend.setdefault(label, handle)
    fig.legend(list(legend.values()), list(legend), loc='lower center', ncol=4, fontsize=8)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout(rect=(0, 0.07, 1, 0.96))
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return str(path)


def plot(report: dict, out: Path) -> list[str]:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter, NullFormatter

    effects = list(report['thresholds'])
    styles = {'correct': ('C2', 'o', 'correct'), 'confounded_truth': ('C0', 's', 'confounded incl. truth'),
              'missed': ('C7', 'v', 'missed (nothing missing)'), 'wrong': ('C3', 'x', 'wrong name / confounded w/o'),
              'unexplained': ('C1', 'd', 'unexplained'), 'drift': ('C4', '^', 'drift'), 'crash': ('k', '*', 'crash')}
    written = []

    def rates(points, key):
        n = [p['runs'] for p in points]
        out_rates = {}
        for outcome in styles:
            counts = [p['counts'][outcome] + (p['counts']['confounded_other'] if outcome == 'wrong' else 0)
                      for p in points]
            out_rates[outcome] = [c / m if m else float('nan') for c, m in zip(counts, n)]
        return [p[key] for p in points], out_rates

    columns = 3
    panels = len(effects) + 1
    rows = math.ceil(panels / columns)
    fig, axes = plt.subplots(rows, columns, figsize=(4.2 * columns, 3.2 * rows), squeeze=False)
    for ax, effect in zip(axes.flat, effects):
        points = sorted((p for p in report['vs_psnr'] if p['effect'] == effect), key=lambda p: p['psnr'])
        x, r = rates(points, 'psnr')
        for outcome, (color, marker, label) in styles.items():
            if any(v > 0 for v in r[outcome]) or outcome in ('correct', 'wrong', 'missed'):
                ax.plot(x, r[outcome], color=color, marker=marker, label=label)
        ax.set_title(f'{effect} (typical)', fontsize=9)
        ax.set_xlabel('PSNR [dB]')
        ax.set_ylim(-0.05, 1.05)
        ax.axvline(50, color='0.8', lw=0.8, ls='--')
        ax.grid(alpha=0.3)
    ax = axes.flat[len(effects)]
    points = sorted((p for p in report['clean'] if p.get('chain', UNKNOWN_CHAIN) == UNKNOWN_CHAIN
                     and p['false_alarm_rate'] is not None), key=lambda p: p['psnr'])
    ax.plot([p['psnr'] for p in points], [p['false_alarm_rate'] for p in points], color='C3', marker='x',
            label='false alarm')
    ax.set_title('clean data: false-alarm rate', fontsize=9)
    ax.set_xlabel('PSNR [dB]')
    ax.set_ylim(-0.05, 1.05)
    ax.grid(alpha=0.3)
    written.append(_finish(fig, axes, panels, f'Rate of each diagnosis outcome vs PSNR ({report["seeds"]} '
                           'seeds/point)', out / 'rate_vs_psnr.png'))

    rows = math.ceil(len(effects) / columns)
    fig, axes = plt.subplots(rows, columns, figsize=(4.2 * columns, 3.2 * rows), squeeze=False)
    for ax, effect in zip(axes.flat, effects):
        points = sorted((p for p in report['vs_magnitude'] if p['effect'] == effect
                         and p.get('chain', UNKNOWN_CHAIN) == UNKNOWN_CHAIN), key=lambda p: p['factor'])
        entry = report['thresholds'][effect]
        x = [p['factor'] * entry['typical'] for p in points]
        _, r = rates(points, 'factor')
        for outcome, (color, marker, label) in styles.items():
            if any(v > 0 for v in r[outcome]) or outcome in ('correct', 'wrong', 'missed'):
                ax.plot(x, r[outcome], color=color, marker=marker, label=label)
        known = sorted((p for p in report['vs_magnitude'] if p['effect'] == effect and p.get('chain') == KNOWN_CHAIN),
                       key=lambda p: p['factor'])
        if known:
            ax.plot([p['factor'] * entry['typical'] for p in known], rates(known, 'factor')[1]['correct'], color='C2',
                    ls='--', marker='o', mfc='none', label='correct, chain known')
        ax.set_xscale('log')
        ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f'{v:g}'))
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_xticks(x)
        ax.tick_params(axis='x', labelrotation=45, labelsize=7)
        if entry['value'] is not None:
            ax.axvline(entry['value'], color='C2', ls=':', lw=1.2)
            ax.annotate(f'{entry["value"]:.3g}', (entry['value'], 0.5), color='C2', fontsize=8, rotation=90,
                        ha='right')
        ax.axvline(entry['typical'], color='0.8', lw=0.8, ls='--')
        ax.set_title(effect, fontsize=9)
        ax.set_xlabel(f'{entry["parameter"]} [{entry["unit"]}]')
        ax.set_ylim(-0.05, 1.05)
        ax.grid(alpha=0.3)
    written.append(_finish(fig, axes, len(effects), f'Outcome rate vs effect magnitude at {MAGNITUDE_PSNR:g} dB '
                           '(dotted: smallest reliably correct; dashed: typical)', out / 'rate_vs_magnitude.png'))
    return written


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--quick', action='store_true',
                        help=f'{QUICK_SEEDS} seeds, PSNR {QUICK_PSNRS}, magnitudes {QUICK_MAGNITUDES} (~3 min)')
    parser.add_argument('--seeds', type=int, help=f'seeds per point (default {SEEDS}, --quick {QUICK_SEEDS})')
    parser.add_argument('--effects', nargs='+', help='catalog effects to test (default: the whole catalog)')
    parser.add_argument('--workers', type=int, default=2, help='worker processes (default 2)')
    parser.add_argument('--out', type=Path, default=ROOT / 'bench' / 'results' / 'robustness',
                        help='directory for robustness.json, robustness.md and the PNG plots')
    parser.add_argument('--json', type=Path, help='where to write the JSON (default OUT/robustness.json)')
    parser.add_argument('--varied', action='store_true',
                        help='simulate with every nominal parameter moved by 20 %% instead of the defaults')
    parser.add_argument('--known-chain', action='store_true',
                        help='also run curve (b) and the clean points with the measurement chain known to the '
                             'diagnosis: the simulated angle-filter delay held fixed (as --fix angle_filter=DELAY)')
    parser.add_argument('--chain-filter', type=float, default=0.0, metavar='DELAY',
                        help='simulate every record with an angle filter of this delay [s] (the rig: 0.0141); '
                             'angle_filter is then not a hidden effect of its own')
    parser.add_argument('--no-plots', action='store_true')
    args = parser.parse_args(argv)
    effects = args.effects or list(CATALOG)
    unknown = [e for e in effects if e not in CATALOG]
    if unknown:
        parser.error(f'unknown effect(s) {unknown}; known: {", ".join(CATALOG)}')
    if not 0.0 <= args.chain_filter <= 0.05:
        parser.error(f'--chain-filter {args.chain_filter:g} s: give the filter delay in seconds, 0 to 0.05')
    if args.chain_filter > 0.0:
        effects = [e for e in effects if e != 'angle_filter']     # the filter is part of the chain
        if not effects:
            parser.error('--chain-filter with only angle_filter: the filter is the chain, not a hidden effect')
    seeds = args.seeds or (QUICK_SEEDS if args.quick else SEEDS)
    if seeds < 1 or args.workers < 1:
        parser.error('--seeds and --workers must be at least 1')
    psnrs = QUICK_PSNRS if args.quick else PSNRS
    magnitudes = QUICK_MAGNITUDES if args.quick else MAGNITUDES
    cases = build_cases(effects, psnrs, magnitudes, seeds, args.known_chain, args.chain_filter)
    for case in cases:
        case['varied'] = args.varied
    args.out.mkdir(parents=True, exist_ok=True)
    json_path = args.json or args.out / 'robustness.json'
    json_path.parent.mkdir(parents=True, exist_ok=True)
    print(f'{len(cases)} diagnoses ({len(effects)} effects + clean, {seeds} seeds/point) on {args.workers} '
          f'worker(s)', flush=True)
    started = time.perf_counter()
    runs = []
    os.environ.setdefault('OMP_NUM_THREADS', '1')
    context = get_context('fork') if sys.platform.startswith('linux') else get_context()
    chains = (UNKNOWN_CHAIN, KNOWN_CHAIN) if args.known_chain else (UNKNOWN_CHAIN,)
    curves = [(e, c) for c in chains for e in effects if c == UNKNOWN_CHAIN or e != 'angle_filter']
    factors = {curve: sorted(magnitudes) for curve in curves}
    with context.Pool(args.workers, initializer=_worker_init) as pool:
        while cases:
            for run in pool.imap_unordered(run_case, cases):
                runs.append(run)
                named = ','.join(run['named']) or '-'
                print(f'[{len(runs):3d}] {run["effect"]:17s} x{run["factor"]:<9.4g} {run["psnr"]:4.0f} dB '
                      f'seed {run["seed"]}: {run["outcome"]:16s} {named:30s} {run["seconds"]:5.1f} s', flush=True)
            cases = []
            for effect, chain in curves:     # still found at the smallest magnitude: halve it until it is not
                smallest = factors[effect, chain][0]
                if smallest / 2 >= SMALLEST_FACTOR and \
                        summarise(runs, effect, smallest, MAGNITUDE_PSNR, chain)['correct_rate'] >= RELIABLE:
                    factors[effect, chain].insert(0, smallest / 2)
                    cases += [{'effect': effect, 'factor': smallest / 2, 'psnr': MAGNITUDE_PSNR, 'seed': s,
                               'varied': args.varied, 'chain': chain, 'chain_filter': args.chain_filter}
                              for s in range(1, seeds + 1)]
            if cases:
                extended = sorted({f'{c["effect"]} (chain {c["chain"]})' for c in cases})
                print(f'extending downwards: {", ".join(extended)}', flush=True)
    wall = time.perf_counter() - started
    runs.sort(key=lambda r: (r['effect'], r.get('chain', UNKNOWN_CHAIN), r['factor'], -r['psnr'], r['seed']))
    vs_psnr = [summarise(runs, e, 1.0, p) for e in effects for p in psnrs]
    vs_magnitude = [summarise(runs, e, f, MAGNITUDE_PSNR, c) for e, c in curves for f in factors[e, c]]
    clean = [summarise(runs, CLEAN, 0.0, p, c) for c in chains for p in psnrs]
    thresholds: dict[str, dict] = {}
    thresholds_known: dict[str, dict] = {}
    for effect, chain in curves:
        parameter = get_effect(effect).parameters[0]
        best = smallest_reliable([p for p in vs_magnitude if p['effect'] == effect and p['chain'] == chain])
        (thresholds if chain == UNKNOWN_CHAIN else thresholds_known)[effect] = {
            'parameter': parameter.name, 'unit': parameter.unit, 'typical': parameter.typical,
            'factor': best['factor'] if best else None, 'value': best['factor'] * parameter.typical if best else None,
            'tested_factors': factors[effect, chain]}
    report = {'date': datetime.now(timezone.utc).strftime('%Y-%m-%d %H:%M UTC'),
              'machine': f'{platform.node()} {platform.machine()} {os.cpu_count()} cpu',
              'quick': args.quick, 'varied_parameters': args.varied, 'seeds': seeds,
              'seed_base': SEED_BASE, 'duration_s': DURATION,
              'psnrs': list(psnrs), 'magnitudes': list(magnitudes), 'magnitude_psnr': MAGNITUDE_PSNR,
              'default_max_duty': DEFAULT_MAX_DUTY, 'large_angle_deg': math.degrees(LARGE_ANGLE),
              'reliable_fraction': RELIABLE,
              'workers': args.workers, 'runs': len(runs), 'wall_seconds': wall,
              'mean_diagnosis_seconds': sum(r['seconds'] for r in runs) / len(runs),
              'outcome_totals': {o: sum(r['outcome'] == o for r in runs) for o in OUTCOMES},
              'measurement_chain': {'simulated_filter_delay_s': args.chain_filter, 'known_rows': args.known_chain,
                                    'known_means': 'angle_filter held at the simulated delay (fixed= of diagnose, '
                                                   'as --fix angle_filter=DELAY / --calibration)'},
              'vs_psnr': vs_psnr, 'vs_magnitude': vs_magnitude, 'clean': clean, 'thresholds': thresholds,
              'thresholds_known_chain': thresholds_known,
              'cases': runs}
    json_path.write_text(json.dumps(_plain(report), indent=1))
    text = markdown(report)
    (args.out / 'robustness.md').write_text(text)
    written = [str(json_path), str(args.out / 'robustness.md')]
    if not args.no_plots:
        written += plot(report, args.out)
    print(text)
    print(f'wall time {wall:.0f} s; wrote ' + ', '.join(written))
    crashes = report['outcome_totals']['crash']
    if crashes:
        print(f'{crashes} diagnosis run(s) crashed; tracebacks in {json_path}', file=sys.stderr)
        return 1
    return 0


if __name__ == '__main__':
    sys.exit(main())

"""Does the closed loop close? Identify the rig open loop, design on the identified model, run on the rig with a
hidden effect, check, diagnose, add, redesign, run again (issue #39's benchmark, in the paper's order).

For each case (10 clean seeds, and 10 seeds of each hidden effect: thrust lag 0.1-0.2 s, dead zone, Coulomb
friction, angle offset), on fresh seeds:

* the truth: the simulator with every pendulum and motor parameter scaled by U(0.85, 1.15), the hidden effect at a
  random size, 40 dB angle noise on the stream's full scale and the rig's 10-bit angle;
* ``identified``: what a user does first: the open-loop excitation ``aeropend simulate`` plays (60 s Latin-hypercube
  duty up to 0.7) on the truth, 40 dB on each stream's full scale (the closed-loop runs' noise: one sensor;
  ``--record-peak-noise``: s21's quieter record, 40 dB on its own peak), diagnosed as ``aeropend diagnose`` does
  (:func:`diagnose`: the nominal structure's fit; whether it already names the hidden effect is recorded);
* ``structure``: the design on that nominal-structure model (``control design --model DIAGNOSIS.json --record``:
  its parameters, its motor observer, its noise, its thrust doubt; 40 deg, settling <= 2 s, overshoot <= 10 %,
  error <= 5 %, duty <= 0.8) run on the truth (the compiled closed loop: the same law and simulator the sim node
  runs) over its design schedule, judged by ``control check`` (:func:`check_record`): does the check say so where
  it really misses?
* ``nominal`` (the user's first design): where the open-loop diagnosis names effects, the design on the model with
  them added (``aeropend diagnose OPEN_LOOP --add NAME --json M.json``, then ``control design --model M.json
  --record OPEN_LOOP``), else the structure's design; run on the truth and checked. A refusal is checked against
  the design on the *true* model (its parameters and hidden effect, no thrust doubt): when that refuses too, the
  seed is "refused, correctly"; ``path`` says which model each seed's first design was on;
* ``nominal_parameters``: the old column, the design on the nominal parameters (no identification), run and judged;
* ``loop``: where the first design missed, the closed-loop diagnosis of its record (:func:`diagnose_loop`, with
  the first model's effects added), the named effect added (``--add``), the diagnosis again with it, the design on
  that model (its measured noise), the new gains run on the truth and checked;
* ``predict``: on the model the loop ended on (the first one where it met), a different controller (its gains x
  0.7 on p and d, other steps: 25 -> 50 -> 30 deg) predicted on that model and measured on the truth: overshoot and
  settling compared (one draw of the model, and since s26 the median of 20 draws, the point `control check`
  gives), and whether the measured settling lies in the range of 20 noise draws of the model (what `control check`
  gives since s23: the settling of one noisy run is not a point the model can predict).

    nice -n 10 python bench/closed_loop.py --seeds 10 --workers 2 --out bench/results/2026-12-07-s21-closed-loop
    python bench/closed_loop.py --seeds 2 --cases clean,thrust_lag        # a quick look

Writes ``cases.json`` (every record) and prints the table; the README in the results folder is written from it.
"""
from __future__ import annotations

import argparse
import json
import math
import time
import warnings
from pathlib import Path

import numpy as np

from aeropend_core.control.check import SETTLING_DRAWS, check_record, settling_ranges
from aeropend_core.control.controller_file import Controller
from aeropend_core.control.design import TemplateNotMet, design
from aeropend_core.control.hold_doubt import HoldDoubt, hold_doubt
from aeropend_core.control.loop import FeedforwardMap, simulate_loop
from aeropend_core.control.loop_diagnosis import diagnose_loop
from aeropend_core.control.metrics import Template, schedule_metrics
from aeropend_core.control.model_source import model_from_dict
from aeropend_core.control.reference import ReferenceSchedule
from aeropend_core.diagnosis.diagnose import diagnose
from aeropend_core.errors import AeropendError
from aeropend_core.io.recording import from_columns
from aeropend_core.model.parameters import DEFAULT_PARAMETERS, SAMPLE_TIME, RigParameters
from aeropend_core.present.json_output import finite_json
from aeropend_core.sim.excitation import lhc_schedule
from aeropend_core.sim.noise import MeasurementNoise, apply_measurement_noise
from aeropend_core.sim.simulate import simulate

TEMPLATE = Template()
AT = math.radians(40)
PSNR = 40.0
#: fresh seeds (s17 used 90000+, s19 91000+; s20 developed on 95000+ and reports 96000+;
#: s21 reports 97000+); --seed-base
SEED_BASE = 97_000
CASES = ('clean', 'thrust_lag', 'dead_zone', 'coulomb_friction', 'angle_offset')
#: parameters scaled by U(0.85, 1.15) in the truth (eq (8)'s fit and the gear are kept: they are measured)
SCALED = ('armature_resistance', 'armature_inductance', 'back_emf_constant', 'torque_constant', 'motor_inertia',
          'motor_friction', 'propeller_torque_coefficient', 'thrust_coefficient', 'gravity_stiffness', 'damping',
          'lever_per_inertia')


def truth_of(case: str, rng: np.random.Generator) -> tuple[RigParameters, dict]:
    scales = {name: float(rng.uniform(0.85, 1.15)) for name in SCALED}
    parameters = DEFAULT_PARAMETERS.scaled(**scales)
    effect = {'clean': {}, 'thrust_lag': {'thrust_lag': {'time_constant': float(rng.uniform(0.1, 0.2))}},
              'dead_zone': {'dead_zone': {'threshold_voltage': float(rng.uniform(0.5, 1.0))}},
              'coulomb_friction': {'coulomb_friction': {'friction_acceleration': float(rng.uniform(2.0, 6.0))}},
              'angle_offset': {'angle_offset': {'angle_offset': float(rng.choice([-1, 1]) * rng.uniform(0.02, 0.06))}}
              }[case]
    return parameters, effect


def run_on_truth(controller: Controller, schedule: ReferenceSchedule, parameters, effects, seed: int):
    return simulate_loop(controller.gains, schedule.reference(),
                         FeedforwardMap(controller.parameters, controller.effects), parameters, effects,
                         MeasurementNoise(psnr_db=PSNR, quantise=True), seed, duty_limit=controller.gains.u_clamp_max)


def judged(controller: Controller, schedule: ReferenceSchedule, run, seed: int) -> dict:
    result = check_record(run.time, run.angle, run.duty, controller, schedule, TEMPLATE, seed=seed + 7)
    return {'met': result.met, 'verdict': result.verdict,
            'measured_misses': [step.measured_misses for step in result.steps],
            'predicted_misses': [step.predicted_misses for step in result.steps],
            'overshoot': [step.measured.overshoot for step in result.steps],
            'settling': [step.measured.settling_time if step.measured.settled else None for step in result.steps]}


def loop_diagnosis(controller: Controller, run, add=()) -> dict:
    diagnosis = diagnose_loop(run.time, run.angle, run.duty, run.reference, run.feedforward, controller.gains,
                              controller.gains.u_clamp_max, controller.parameters, add=add,
                              model_effects=controller.effects)
    return diagnosis.to_dict()


def identify_open_loop(parameters, effects, seed: int, full_scale_noise: bool = True) -> tuple[dict, dict]:
    """The user's first step on the rig: the open-loop excitation `aeropend simulate` plays (60 s Latin-hypercube
    duty up to 0.7) on the truth, 40 dB and the 10-bit angle, diagnosed as `aeropend diagnose` does. A rig strong
    enough to swing the rod past 85 deg at duty 0.7 is excited again with the top duty 0.1 lower (what the
    diagnosis's note asks: "keep the duty steps below the level that holds the rod at ~85 deg"). The record's noise
    is the closed-loop runs' (40 dB on each stream's full scale, `full_scale_noise`): a rig has one sensor, and an
    open-loop record quieter than the loop made the design predict too small a steady-state error (s21: the angle
    noise was 0.009-0.014 rad on the record's own peak, 0.0157 in the loop). Returns the
    diagnosis's numbers and the record's columns (its rests check every model designed on: `--record`)."""
    for max_duty in (0.7, 0.6, 0.5, 0.4):
        duty = lhc_schedule(60.0, duty_range=(0.0, max_duty), duty_cap=max_duty, seed=seed).duty(SAMPLE_TIME, 60.0)
        if not full_scale_noise:
            trajectory = simulate(duty, parameters, effects or None, noise=MeasurementNoise(PSNR, True), seed=seed)
        else:
            # the rig's one sensor chain: 40 dB on each stream's full scale, as in the closed-loop runs
            # (simulate_loop); `simulate`'s noise is on the record's own peak, which made the open-loop record's
            # angle noise 0.009-0.014 rad where the closed-loop runs had 0.0157 (s20, s21)
            trajectory = simulate(duty, parameters, effects or None, seed=seed)
            clean = {'armature_voltage': trajectory.armature_voltage,
                     'armature_current': trajectory.armature_current, 'angle': trajectory.angle}
            noisy = apply_measurement_noise(clean, MeasurementNoise(PSNR, True), np.random.default_rng(seed + 17))
            trajectory.armature_voltage, trajectory.armature_current, trajectory.angle = (
                noisy['armature_voltage'], noisy['armature_current'], noisy['angle'])
        columns = trajectory.columns(with_truth=False)
        if np.max(columns['angle']) < math.radians(85):
            break
    started = time.perf_counter()
    found = diagnose(from_columns(columns))
    data = finite_json(found.to_dict())
    model = model_from_dict(data, 'open-loop diagnosis')
    doubt = hold_doubt(columns['t'], columns['angle'], columns['duty'], model.parameters, model.effects)
    held = {'hold_doubt': None if doubt is None else {'factors': list(doubt.factors), 'tolerance': doubt.tolerance}}
    keys = ('verdict', 'missing_effect', 'missing_effects', 'model_effects', 'parameters', 'standard_errors',
            'noise_rms', 'parameter_warnings', 'warnings', 'motor_observer')
    numbers = held | {key: data.get(key) for key in keys} | {'seconds': time.perf_counter() - started,
                                                              'max_duty': max_duty}
    return numbers, columns


def open_loop_names(identified: dict) -> tuple[str, ...]:
    """The effects the open-loop diagnosis says to add (its ``missing_effects``; none when it names nothing or
    says its candidates are confounded)."""
    if not str(identified.get('verdict') or '').startswith('effect'):
        return ()
    names = [entry.get('effect') if isinstance(entry, dict) else entry
             for entry in identified.get('missing_effects') or []]
    return tuple(str(name) for name in names if name)


def diagnosed_with(open_loop: dict, added: tuple[str, ...], use_hold_doubt: bool):
    """`aeropend diagnose OPEN_LOOP --add NAME --json M.json` then `control design --model M.json --record
    OPEN_LOOP`: the model the JSON holds (the nominal structure with `added`, fitted on the open-loop record), its
    thrust doubt checked on the record's rests. The per-segment drift test is skipped (``--no-drift``: it changes
    no parameter)."""
    found = diagnose(from_columns(open_loop), effects=added, drift=False)
    model = model_from_dict(finite_json(found.to_dict()), 'open-loop diagnosis --add')
    if use_hold_doubt:
        model = model.with_hold_doubt(hold_doubt(open_loop['t'], open_loop['angle'], open_loop['duty'],
                                                 model.parameters, model.effects))
    return model


def design_on(model, name: str) -> tuple[Controller | None, str, dict]:
    """`control design --model`: the controller, or None and the refusal (with its items)."""
    try:
        result = design(TEMPLATE, AT, model.parameters, model.effects,
                        noise=MeasurementNoise(psnr_db=model.psnr_db, quantise=True),
                        thrust_tolerance=model.thrust_tolerance)
    except TemplateNotMet as refusal:
        return None, f'refused: {refusal}', dict(refusal.misses)
    except AeropendError as refusal:
        return None, f'refused: {refusal}', {}
    return (Controller(result.gains, model.parameters, model.effects, TEMPLATE, name, result.summary()), 'designed',
            {})


def truth_refuses(parameters, effects, thrust_tolerance: tuple[float, float] = (1.0, 1.0)) -> bool:
    """Whether the design on the *true* model (its parameters and hidden effect, 40 dB) refuses under
    `thrust_tolerance` (default none: s21-s23's criterion): then no gains of the search meet the template on the rig
    itself (with that doubt), and a refusal on an identified model is correct."""
    try:
        design(TEMPLATE, AT, parameters, effects, noise=MeasurementNoise(psnr_db=PSNR, quantise=True),
               thrust_tolerance=tuple(thrust_tolerance))
    except (TemplateNotMet, AeropendError):
        return True
    return False


def judge_refusal(record: dict, parameters, effects, thrust_tolerance) -> None:
    """A refusal judged twice into `record`: ``truth_refuses`` (the truth designed with no thrust doubt, the s21-s23
    column) and ``truth_refuses_like_for_like`` (the truth designed under the same doubt, `thrust_tolerance`, as the
    refused model's design: a refusal the truth shares under that doubt is correct; s23 dead zone 4 at 93000)."""
    record['truth_refuses'] = truth_refuses(parameters, effects)
    record['refused_thrust_tolerance'] = list(thrust_tolerance)
    if tuple(thrust_tolerance) == (1.0, 1.0):
        record['truth_refuses_like_for_like'] = record['truth_refuses']
    else:
        record['truth_refuses_like_for_like'] = truth_refuses(parameters, effects, thrust_tolerance)


def refused_correctly(record: dict, like_for_like: bool) -> bool | None:
    """Whether `record`'s refusal (first design or redesign) is correct: the truth's design refuses too, with no
    doubt (`like_for_like` False: the old column) or under the refused design's doubt (True); None when the row
    has no such judgement (a row written before s24 has no like-for-like one)."""
    key = 'truth_refuses_like_for_like' if like_for_like else 'truth_refuses'
    return None if record.get(key) is None else bool(record[key])


def _correct_refusals(rows: list[dict]) -> str:
    """The table's cell: refusals correct with no doubt; under the same doubt ('?' for rows never judged so)."""
    cells = []
    for like_for_like in (False, True):
        judged_rows = [refused_correctly(r, like_for_like) for r in rows]
        unjudged = sum(verdict is None for verdict in judged_rows)
        cells.append(f'{sum(bool(verdict) for verdict in judged_rows)}' + (f' (+{unjudged} ?)' if unjudged else ''))
    return '; '.join(cells)


def one_case(job) -> dict:
    try:
        return _one_case(job)
    except Exception as error:          # a crash is a result: said in the table, not a lost run
        import traceback
        return {'case': job[0], 'seed': job[1], 'error': f'{type(error).__name__}: {error}',
                'traceback': traceback.format_exc()}


def _one_case(job) -> dict:
    case, seed, nominal_parameters, seed_base, use_hold_doubt, full_scale_noise = job
    warnings.simplefilter('ignore')
    rng = np.random.default_rng(seed_base + 1000 * CASES.index(case) + seed)
    parameters, effects = truth_of(case, rng)
    record = {'case': case, 'seed': seed, 'truth_effects': effects,
              'truth_scales': {name: getattr(parameters, name) / getattr(DEFAULT_PARAMETERS, name) for name in SCALED}}
    started = time.perf_counter()
    # The old column: the design on the nominal parameters, with no identification.
    run = run_on_truth(nominal_parameters, nominal_parameters.schedule, parameters, effects, seed)
    record['nominal_parameters'] = judged(nominal_parameters, nominal_parameters.schedule, run, seed)
    # 1. identify the rig open loop; 2. design on the identified model (the nominal structure, no hidden effect).
    identified, open_loop = identify_open_loop(parameters, effects, seed_base + 100 * seed + CASES.index(case),
                                               full_scale_noise)
    record['identified'] = identified
    model = model_from_dict(identified, 'open-loop diagnosis')
    record['fit_thrust_tolerance'] = model.thrust_tolerance
    if use_hold_doubt:    # `control design --record`: the record's rests
        held = identified['hold_doubt']
        model = model.with_hold_doubt(None if held is None else HoldDoubt(tuple(held['factors']), (),
                                                                          tuple(held['tolerance'])))
    record['identified_thrust_tolerance'] = model.thrust_tolerance
    # The nominal structure's design, run and checked: does `control check` say so where it really misses?
    design_started = time.perf_counter()
    structure, outcome, refused_items = design_on(model, 'open-loop diagnosis')
    record['design_seconds'] = time.perf_counter() - design_started
    record['structure_design'] = outcome
    if structure is None:
        record['structure_refused_items'] = refused_items
        record['structure'] = {'met': False, 'verdict': 'not run: the design refused', 'refused': True}
    else:
        record['structure_gains'] = structure.gains.as_dict()
        run = run_on_truth(structure, structure.schedule, parameters, effects, seed)
        record['structure'] = judged(structure, structure.schedule, run, seed)
        record['structure']['thrust_edge_misses'] = structure.design.get('thrust_edge_misses')
    # The user's first design: where the open-loop diagnosis names effects, `aeropend diagnose --add` them (its
    # model: the nominal structure with them added, fitted on the same record) and design on that model.
    added_first = open_loop_names(identified)
    record['first_added'] = list(added_first)
    if added_first:
        model = diagnosed_with(open_loop, added_first, use_hold_doubt)
        record['first_model'] = {'effects': model.effects, 'thrust_tolerance': model.thrust_tolerance}
        record['path'] = f'open-loop diagnosis named {", ".join(added_first)}: first design on the model with it added'
        nominal, outcome, refused_items = design_on(model, 'open-loop diagnosis --add')
        record['nominal_design'] = outcome
    else:
        record['path'] = 'open-loop diagnosis named nothing: first design on the nominal structure'
        nominal = structure
        record['nominal_design'] = record['structure_design']
    if nominal is None:
        record['refused_items'] = refused_items
        judge_refusal(record, parameters, effects, model.thrust_tolerance)
        record['nominal'] = {'met': False, 'verdict': 'not run: the design refused', 'refused': True}
        record['diagnosis'] = {'verdict': None, 'named': None, 'confounded_with': []}
        record['loop'] = {'redesign': 'not run: the first design refused', 'met': False}
        record['seconds'] = time.perf_counter() - started
        return record
    record['nominal_gains'] = nominal.gains.as_dict()
    record['nominal_thrust_edge_misses'] = nominal.design.get('thrust_edge_misses')
    if nominal is structure:
        record['nominal'] = record['structure']
    else:
        run = run_on_truth(nominal, nominal.schedule, parameters, effects, seed)
        record['nominal'] = judged(nominal, nominal.schedule, run, seed)
    if record['nominal']['met']:
        record['diagnosis'] = {'verdict': 'not run (the design met the template)', 'named': None,
                               'confounded_with': []}
        record['loop'] = {'redesign': 'not needed (the design met the template)', 'met': True}
        record['predict'] = predict_other(nominal, parameters, effects, seed)
        record['seconds'] = time.perf_counter() - started
        return record
    # The loop: diagnose the closed-loop record (`--add` what the model already has), add what it names (once),
    # design again, run again.
    had = tuple(nominal.effects)
    first = loop_diagnosis(nominal, run, had)
    record['diagnosis'] = {'verdict': first['verdict'], 'named': first['missing_effect'],
                           'confounded_with': first['confounded_with']}
    added = had + tuple(first['add'])
    record['loop_path'] = (f'closed-loop diagnosis named {first["add"][0]}' if first['add']
                           else 'closed-loop diagnosis named nothing')
    # What the tool tells the user: where the closed-loop record cannot separate effects ("confounded ... an
    # open-loop segment would separate them") or names nothing, the open-loop record's diagnosis names the effect
    # (not again when the first design already had it).
    open_named = identified.get('missing_effect')
    if open_named and open_named not in had and (not first['add'] or first['confounded_with']) \
            and open_named not in added:
        added = had + (open_named,)
        record['loop_path'] = (f'open-loop diagnosis named {open_named} (the closed-loop one '
                               + (f'confounded {first["missing_effect"]} with {", ".join(first["confounded_with"])})'
                                  if first['confounded_with'] else 'named nothing)'))
    record['loop_added'] = list(added)
    diagnosis = loop_diagnosis(nominal, run, added) if added != had else first
    record['diagnosis']['after_add'] = diagnosis['verdict']
    record['diagnosis']['parameters'] = diagnosis['parameters']
    record['diagnosis']['standard_errors'] = diagnosis['standard_errors']
    base = model_from_dict({**diagnosis, 'parameters': {**diagnosis['parameters']}}, 'loop diagnosis')
    record['loop_fit_thrust_tolerance'] = base.thrust_tolerance
    if use_hold_doubt:      # `control design --model loop.json --record OPEN_LOOP`: the same rests check this model
        base = base.with_hold_doubt(hold_doubt(open_loop['t'], open_loop['angle'], open_loop['duty'],
                                               base.parameters, base.effects))
    model_parameters = base.parameters
    try:
        noise_db = min(80.0, 20 * math.log10((math.pi / 2) / max(diagnosis['noise_rms'], 1e-9)))
        redesign = design(TEMPLATE, AT, model_parameters, base.effects,
                          noise=MeasurementNoise(psnr_db=noise_db, quantise=True),
                          thrust_tolerance=base.thrust_tolerance)
        record['loop_thrust_tolerance'] = base.thrust_tolerance
        controller = Controller(redesign.gains, model_parameters, base.effects, TEMPLATE, 'loop diagnosis',
                                redesign.summary())
        again = run_on_truth(controller, controller.schedule, parameters, effects, seed + 500)
        record['loop'] = {'redesign': 'designed', 'gains': controller.gains.as_dict(),
                          'thrust_edge_misses': redesign.summary()['thrust_edge_misses'],
                          **judged(controller, controller.schedule, again, seed + 500)}
        record['predict'] = predict_other(controller, parameters, effects, seed)
    except (TemplateNotMet, AeropendError) as refusal:
        record['loop'] = {'redesign': f'refused: {refusal}', 'met': False}
        judge_refusal(record, parameters, effects, base.thrust_tolerance)
    record['seconds'] = time.perf_counter() - started
    return record


def predict_other(controller: Controller, parameters, effects, seed: int) -> dict:
    """Another controller no fit used (p and d x 0.7, other steps): predicted on the diagnosed model vs measured."""
    other = Controller(controller.gains.replace(p=0.7 * controller.gains.p, d=0.7 * controller.gains.d),
                       controller.parameters, controller.effects, TEMPLATE, 'other')
    schedule = ReferenceSchedule.steps_between([25, 50, 30], hold=5.0, start_hold=3.0)
    measured = run_on_truth(other, schedule, parameters, effects, seed + 900)
    predicted = simulate_loop(other.gains, schedule.reference(), FeedforwardMap(other.parameters, other.effects),
                              other.parameters, other.effects, MeasurementNoise(psnr_db=PSNR, quantise=True),
                              seed + 901, duty_limit=other.gains.u_clamp_max)
    m = schedule_metrics(measured.time, measured.angle, measured.duty, schedule)
    p = schedule_metrics(predicted.time, predicted.angle, predicted.duty, schedule)
    # the settling's range over 19 more noise draws of the model, as `control check` gives it
    ranges = settling_ranges(other.gains, predicted.reference, predicted.feedforward, other.parameters,
                             other.effects, MeasurementNoise(psnr_db=PSNR, quantise=True), schedule,
                             range(seed + 902, seed + 902 + SETTLING_DRAWS), p, duty_limit=other.gains.u_clamp_max)
    rows = []
    for a, b in zip(m, p):
        low, high, draws, unsettled, median = ranges[round(b.start, 6)]
        rows.append({'overshoot_measured': a.overshoot, 'overshoot_predicted': b.overshoot,
                     'settling_measured': a.settling_time, 'settling_predicted': b.settling_time,
                     'overshoot_ok': abs(a.overshoot - b.overshoot) <= 3.0,
                     'settling_ok': abs(a.settling_time - b.settling_time) <= 0.2 * max(a.settling_time, 1e-9),
                     'settling_median': median,
                     'settling_median_ok': abs(a.settling_time - median) <= 0.2 * max(a.settling_time, 1e-9),
                     'settling_range': [low, high, draws, unsettled],
                     'settling_in_range': low - 1e-9 <= a.settling_time <= high + 1e-9})
    return {'steps': rows}


def table(records: list[dict]) -> str:
    lines = ['| case | seeds | open loop named (correct) | first design on the model with it added '
             '| nominal structure met | nominal structure missed (check said missed) | first design refused '
             '(correctly: truth with no doubt; under the same doubt) | first design met | closed-loop named (correct) '
             '| loop met | refused, correctly (no doubt; same doubt) '
             '| predict: overshoot within 3 pp | predict: settling within 20 % (one draw; median of 20) '
             '| predict: settling in 20-draw range '
             '| design s | s/seed |',
             '|' + '---|' * 16]
    errors = [r for r in records if 'error' in r]
    records = [r for r in records if 'error' not in r]
    for case in CASES:
        rows = [r for r in records if r['case'] == case]
        if not rows:
            continue
        truth_name = None if case == 'clean' else case
        open_named = sum(r['identified']['missing_effect'] is not None for r in rows)
        open_correct = sum(r['identified']['missing_effect'] == truth_name for r in rows
                           if r['identified']['missing_effect'] is not None)
        first_added = sum(bool(r.get('first_added')) for r in rows)
        structure_met = sum(r['structure']['met'] for r in rows)
        ran = [r for r in rows if not r['structure'].get('refused')]
        structure_missed = [r for r in ran if not r['structure']['met']]
        said = sum(not r['structure']['verdict'].startswith('meets') for r in structure_missed)
        refused = [r for r in rows if r['nominal'].get('refused')]
        refused_correct = _correct_refusals(refused)
        nominal_met = sum(r['nominal']['met'] for r in rows)
        named = sum(r['diagnosis']['named'] is not None for r in rows)
        correct = sum(r['diagnosis']['named'] == truth_name for r in rows if r['diagnosis']['named'] is not None)
        loop_met = sum(bool(r['loop'].get('met')) for r in rows)
        correctly = _correct_refusals([r for r in rows if not r['loop'].get('met') and (
            r['nominal'].get('refused') or str(r['loop'].get('redesign', '')).startswith('refused'))])
        steps = [s for r in rows for s in r.get('predict', {}).get('steps', [])]
        overshoot = f'{sum(s["overshoot_ok"] for s in steps)}/{len(steps)}'
        medians = [s for s in steps if 'settling_median_ok' in s]       # rows before s26 have one draw only
        settling = (f'{sum(s["settling_ok"] for s in steps)}/{len(steps)}'
                    + (f' (median {sum(s["settling_median_ok"] for s in medians)}/{len(medians)})' if medians else ''))
        ranged = [s for s in steps if 'settling_in_range' in s]
        in_range = f'{sum(s["settling_in_range"] for s in ranged)}/{len(ranged)}' if ranged else '-'
        design_seconds = np.median([r['design_seconds'] for r in rows])
        seconds = np.mean([r['seconds'] for r in rows])
        lines.append(f'| {case} | {len(rows)} | {open_named} ({open_correct}) | {first_added} | {structure_met} | '
                     f'{len(structure_missed)} ({said}) | {len(refused)} ({refused_correct}) | {nominal_met} | '
                     f'{named} ({correct}) | {loop_met} | {correctly} | '
                     f'{overshoot} | {settling} | {in_range} | {design_seconds:.1f} | {seconds:.0f} |')
    lines += [f'\ncrashed: {r["case"]} seed {r["seed"]}: {r["error"]}' for r in errors]
    lines += ['', 'Path of each seed (thrust tolerance: the nominal structure\'s fit, then the first design\'s with '
              'the record\'s rests):', '']
    for r in sorted(records, key=lambda r: (CASES.index(r['case']), r['seed'])):
        fit, used = r.get('fit_thrust_tolerance'), r.get('identified_thrust_tolerance')
        if r.get('first_model'):        # the first design's model: the one with the open-loop name added
            used = r['first_model']['thrust_tolerance']
        tolerance = (f'{fit[0]:.3f}-{fit[1]:.3f} -> {used[0]:.3f}-{used[1]:.3f}' if fit and used else '-')
        gains = r.get('nominal_gains') or {}
        after = ('met' if r['loop'].get('met') else 'missed') if r['loop'].get('redesign') == 'designed' else (
            r['loop'].get('redesign', '')[:50])
        structure = 'refused' if r['structure'].get('refused') else ('met' if r['structure']['met'] else 'missed')
        first = 'refused' if r['nominal'].get('refused') else ('met' if r['nominal']['met'] else 'missed')
        lines.append(f'- {r["case"]} {r["seed"]}: nominal structure {structure}; {r.get("path", "")}; tolerance '
                     f'{tolerance}, i {gains.get("i", math.nan):.3g}; first design {first}; '
                     + (f'{r.get("loop_path", "")}, added {r.get("loop_added")}, redesign {after}'
                        if not r['nominal']['met'] else 'no redesign'))
    return '\n'.join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--seeds', type=int, default=10)
    parser.add_argument('--first-seed', type=int, default=0, help='first seed index (default 0)')
    parser.add_argument('--seed-base', type=int, default=SEED_BASE,
                        help=f'seed of case 0 seed 0 (default {SEED_BASE}: the reported seeds; develop on others)')
    parser.add_argument('--no-hold-doubt', action='store_true',
                        help='design on the identified model with the fit\'s thrust doubt alone (the s19 flow)')
    parser.add_argument('--record-peak-noise', action='store_true',
                        help='the s21 behaviour: the open-loop record\'s noise on the record\'s own peak (1.5-5 dB '
                             'less angle noise than the closed loop; default: on each stream\'s full scale, the '
                             'closed-loop runs\' noise: a rig has one sensor)')
    parser.add_argument('--full-scale-noise', action='store_true',
                        help='the default since s22 (kept so the s21 command still runs)')
    parser.add_argument('--cases', default=','.join(CASES))
    parser.add_argument('--workers', type=int, default=1, help='processes (spawned) running seeds in parallel')
    parser.add_argument('--out', type=Path, default=None)
    parser.add_argument('--table', type=Path, default=None, metavar='CASES.jsonl',
                        help='only print the table of a (partial) run\'s cases.jsonl')
    args = parser.parse_args()
    if args.table:
        print(table([json.loads(line) for line in args.table.read_text().splitlines() if line.strip()]))
        return 0
    warnings.simplefilter('ignore')
    started = time.perf_counter()
    nominal_design = design(TEMPLATE, AT, noise=MeasurementNoise(psnr_db=PSNR, quantise=True))
    nominal = Controller(nominal_design.gains, template=TEMPLATE, design=nominal_design.summary())
    print(f'nominal-parameters design in {time.perf_counter() - started:.1f} s: p {nominal.gains.p:.4g}, '
          f'i {nominal.gains.i:.4g}, d {nominal.gains.d:.4g}, Tf {nominal.gains.derivative_filter_time:.4g}',
          flush=True)
    # seed-major: a run cut short has the same seeds of every case
    jobs = [(case, seed, nominal, args.seed_base, not args.no_hold_doubt, not args.record_peak_noise)
            for seed in range(args.first_seed, args.first_seed + args.seeds)
            for case in args.cases.split(',')]
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
    records = []

    def done(record):          # each seed as it ends: a run cut short keeps what it finished (cases.jsonl)
        records.append(record)
        if 'error' in record:
            print(f'{record["case"]:17s} seed {record["seed"]}: CRASHED {record["error"]}', flush=True)
            return
        print(f'{record["case"]:17s} seed {record["seed"]}: open loop named {record["identified"]["missing_effect"]}, '
              f'structure met {record["structure"]["met"]}, first design ({record.get("first_added")}) met '
              f'{record["nominal"]["met"]} (nominal parameters {record["nominal_parameters"]["met"]}), '
              f'named {record["diagnosis"]["named"]}, loop {record["loop"].get("redesign", "")[:60]} met '
              f'{record["loop"].get("met")} ({record["seconds"]:.0f} s)', flush=True)
        if args.out:
            with open(args.out / 'cases.jsonl', 'a') as stream:
                stream.write(json.dumps(finite_json(record)) + '\n')

    if args.workers > 1:
        from multiprocessing import get_context
        with get_context('spawn').Pool(args.workers) as pool:
            for record in pool.imap_unordered(one_case, jobs):
                done(record)
    else:
        for job in jobs:
            done(one_case(job))
    records.sort(key=lambda r: (CASES.index(r['case']), r['seed']))
    print(table(records))
    if args.out:
        payload = {'nominal_parameters_gains': nominal.gains.as_dict(), 'records': records}
        (args.out / 'cases.json').write_text(json.dumps(finite_json(payload), indent=1))
        (args.out / 'table.md').write_text(table(records) + '\n')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())

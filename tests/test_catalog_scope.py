"""No analysis changes the catalog of effects: what one diagnosis registers for itself (the discovery stage's
``term_*`` effects) is gone when it returns, so two records diagnosed in one process give the same text and JSON in
either order (issue #44).

The records are short (20 s, the least a diagnosis takes): one with a thrust that falls as the rod moves through the
propeller's inflow (outside the catalog: the discovery stage runs and registers terms while it refits them), one
with a 0.15 s thrust lag (a catalog effect). Each order runs in a fresh interpreter, as a user's session would.
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from aeropend_core.errors import AeropendError
from aeropend_core.model.effects import CATALOG, EffectParameter, catalog_scope, get_effect, register_effect

ROOT = Path(__file__).resolve().parents[1]
EFFECTS_MODULE = ROOT / 'bench' / 'discovery_effects.py'

#: One process: simulate both records (the outside effect only while simulating), then diagnose them in the order
#: given on the command line, printing per record its text summary and its JSON (the run time set to 0), and
#: whether the catalog's names after each diagnosis are those before it.
SCRIPT = r'''
import json, sys
from aeropend_core.diagnosis.diagnose import diagnose
from aeropend_core.io.recording import from_columns
from aeropend_core.model.effects import CATALOG, catalog_scope, load_effects_module
from aeropend_core.present.json_output import json_text
from aeropend_core.present.summary import format_summary
from aeropend_core.present.verdict_text import diagnosis_dict
from aeropend_core.sim.excitation import lhc_schedule
from aeropend_core.sim.noise import MeasurementNoise
from aeropend_core.sim.simulate import simulate

def record(effects, seed):
    duty = lhc_schedule(20.0, duty_range=(0.0, 0.7), duty_cap=0.7, seed=seed).duty(duration=20.0)
    columns = simulate(duty, effects=effects, noise=MeasurementNoise(psnr_db=40.0, quantise=True),
                       seed=seed + 1).columns(with_truth=False)
    return from_columns(columns, source=f'seed {seed}')

with catalog_scope():
    load_effects_module(sys.argv[1])
    records = {'inflow': record({'test_inflow': 0.05}, 11), 'lag': record({'thrust_lag': 0.15}, 4)}
out = {}
for name in sys.argv[2:]:
    before = list(CATALOG)
    found = diagnose(records[name], drift=False)
    found.seconds = 0.0         # the run time, the one number that may differ
    data = diagnosis_dict(found)
    out[name] = {'text': format_summary(found), 'json': json_text(data), 'catalog_unchanged': list(CATALOG) == before,
                 'discovery_ran': found.discovery is not None}
print(json.dumps(out))
'''


def test_catalog_scope_undoes_what_was_registered_or_replaced_inside_it():
    names = list(CATALOG)
    offset = get_effect('angle_offset')
    probe = [EffectParameter('scope_probe_k', '1/s^2', 'k', 1.0, 0.0, 2.0)]
    with pytest.raises(AeropendError, match='already registered'):
        with catalog_scope() as catalog:
            register_effect('scope_probe', 'a probe', parameters=probe)(lambda angle, angular_rate, scope_probe_k: 0.0)
            CATALOG['angle_offset'] = CATALOG['scope_probe']        # a replaced record comes back too
            assert catalog is CATALOG and 'scope_probe' in CATALOG
            register_effect('scope_probe', 'again', parameters=probe)(lambda angle, angular_rate, scope_probe_k: 0.0)
    assert list(CATALOG) == names and get_effect('angle_offset') is offset      # put back, also after an error


def test_the_built_in_effects_are_flagged_and_a_users_effect_is_not(scoped_catalog):
    assert all(CATALOG[name].builtin for name in ('thrust_lag', 'angle_offset'))
    register_effect('scope_user', 'a user effect', parameters=[EffectParameter('scope_user_k', '1/s^2', 'k', 1.0)])(
        lambda angle, angular_rate, scope_user_k: 0.0)
    assert not CATALOG['scope_user'].builtin


@pytest.mark.slow
def test_two_records_give_byte_identical_text_and_json_in_either_order_and_leave_the_catalog_alone():
    def run(*order: str) -> dict:
        result = subprocess.run([sys.executable, '-c', SCRIPT, str(EFFECTS_MODULE), *order], capture_output=True,
                                text=True, cwd=ROOT)
        assert result.returncode == 0, result.stderr[-3000:]
        return json.loads(result.stdout.splitlines()[-1])

    first, second = run('inflow', 'lag'), run('lag', 'inflow')
    assert first['inflow']['discovery_ran'], first['inflow']['text']   # the stage that registered terms did run
    for name in ('inflow', 'lag'):
        assert first[name]['catalog_unchanged'] and second[name]['catalog_unchanged'], name
        assert first[name]['text'] == second[name]['text'], name
        assert first[name]['json'] == second[name]['json'], name


def test_the_experiment_loop_leaves_no_lookalike_term_in_the_catalog(monkeypatch):
    """The experiment loop's design registers a discovered lookalike term (``confounded_models``) for the design's
    simulations only: after the loop the catalog holds what it held before (the loop's rounds scripted)."""
    from types import SimpleNamespace

    from aeropend_core.diagnosis import experiment_design, experiment_loop
    from aeropend_core.diagnosis.discovery import term_effect
    from aeropend_core.diagnosis.experiment_design import DesignRefused
    from aeropend_core.diagnosis.experiment_loop import LoopBudget, Played, until_decided
    before = set(CATALOG)
    registered = []

    def confounded_models(diagnosis):
        registered.append(term_effect('thrust*angular_rate'))       # as the lookalike branch does
        return ['catalog set', 'lookalike']

    def design_experiment(models, noise_rms, **options):
        assert registered[-1] in CATALOG                            # there while the design simulates it
        raise DesignRefused('scripted: no schedule')

    monkeypatch.setattr(experiment_loop, 'diagnose_records', lambda records, options: SimpleNamespace(
        verdict='confounded', noise_rms=0.004, found=[], prepared=SimpleNamespace(angle_step=0.0)))
    monkeypatch.setattr(experiment_design, 'confounded_models', confounded_models)
    monkeypatch.setattr(experiment_design, 'design_experiment', design_experiment)
    outcome = until_decided(lambda design, schedule: Played(object(), 'bag 1', 'x', 21.0),
                            LoopBudget(max_runs=3, max_seconds=300.0, design_seconds=20.0))
    assert outcome.verdict == 'refused' and registered and registered[0].startswith('term_')
    assert set(CATALOG) == before, sorted(set(CATALOG) - before)

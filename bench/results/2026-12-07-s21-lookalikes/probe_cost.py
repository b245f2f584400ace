"""The look-alike check alone after the catalog stage, timed (60 s records of bench/lookalikes.py).

Run:  nice -n 10 .venv/bin/python bench/results/2026-12-07-s21-lookalikes/probe_cost.py RECORDS SEED_BASE INDEX...
      (from the repository root; e.g. 3 43000 0 3 6 9)
"""
import sys
import time

sys.path.insert(0, 'bench')
from lookalikes import case, recording_of  # noqa: E402
from threadpoolctl import threadpool_limits  # noqa: E402

from aeropend_core.diagnosis import stages  # noqa: E402
from aeropend_core.diagnosis.discovery import model_states  # noqa: E402
from aeropend_core.diagnosis.lookalike_check import imitators, named_lookalikes  # noqa: E402
from aeropend_core.model.effects import catalog_scope  # noqa: E402


def quiet(message):
    return None


for index in map(int, sys.argv[3:]):
    row = case(index, int(sys.argv[1]), int(sys.argv[2]))
    recording = recording_of(row)
    with threadpool_limits(1), catalog_scope():
        prepared = stages.prepare_stage(recording, (), None, None, None, quiet)
        compared = stages.compare_stage(prepared, quiet)
        cat = stages.catalog_stage(prepared, compared, quiet)
        print(row['seed'], row['truth'], round(row['true_value'], 4), cat.model, 'excess/ref',
              round(cat.excess_final / cat.reference, 3), cat.remainder, [(f.effect, f.parameters) for f in cat.found])
        for f in cat.found:
            ranked = imitators(model_states(cat.prep, cat.current), f.effect)[:4]
            print('  ranking', [(round(share, 3), term.expression) for share, term in ranked])
        started = time.perf_counter()
        found = named_lookalikes(cat.prep, cat.final, cat.current, cat.model, prepared.held,
                                 tuple(f.effect for f in cat.found), print)
        print('  check', round(time.perf_counter() - started, 1), 's',
              found and [(e.term.expression, e.value, e.sigma, e.excess_after, e.differing) for e in found.terms])

import sys, time
sys.path.insert(0, 'bench')
from lookalikes import case, recording_of
from threadpoolctl import threadpool_limits
from aeropend_core.model.effects import catalog_scope
from aeropend_core.diagnosis import stages
from aeropend_core.diagnosis.lookalike_check import named_lookalikes, imitators
from aeropend_core.diagnosis.discovery import model_states
for index in map(int, sys.argv[3:]):
    row = case(index, int(sys.argv[1]), int(sys.argv[2]))
    rec = recording_of(row)
    say = lambda m: None
    with threadpool_limits(1), catalog_scope():
        p = stages.prepare_stage(rec, (), None, None, None, say)
        c = stages.compare_stage(p, say)
        cat = stages.catalog_stage(p, c, say)
        print(row['seed'], row['truth'], round(row['true_value'], 4), cat.model, 'excess/ref', round(cat.excess_final / cat.reference, 3), cat.remainder,
              [(f.effect, f.parameters) for f in cat.found])
        for f in cat.found:
            print('  ranking', [(round(s, 3), t.expression) for s, t in imitators(model_states(cat.prep, cat.current), f.effect)[:4]])
        t = time.perf_counter()
        d = named_lookalikes(cat.prep, cat.final, cat.current, cat.model, p.held, tuple(f.effect for f in cat.found), print)
        print('  check', round(time.perf_counter() - t, 1), 's', d and [(e.term.expression, e.value, e.sigma, e.excess_after, e.differing) for e in d.terms])

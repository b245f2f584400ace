"""bench/closed_loop.py's judging of a refusal: like with like (s24). A refusal of the identified model's design is
correct when the design on the truth refuses too under the same thrust doubt; the old column (the truth with no
doubt) stays beside it so the table compares with s21-s23."""
from __future__ import annotations

import importlib.util
from pathlib import Path

BENCH = Path(__file__).parents[1] / 'bench' / 'closed_loop.py'


def _bench():
    spec = importlib.util.spec_from_file_location('closed_loop_bench', BENCH)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_a_refusal_the_truth_shares_under_the_same_doubt_counts_as_correct_in_the_like_for_like_column(monkeypatch):
    bench = _bench()
    calls = []

    def truth_refuses(parameters, effects, thrust_tolerance=(1.0, 1.0)):
        calls.append(tuple(thrust_tolerance))
        return tuple(thrust_tolerance) != (1.0, 1.0)      # the truth meets with no doubt, refuses under 0.95-1.05

    monkeypatch.setattr(bench, 'truth_refuses', truth_refuses)
    record = {'nominal': {'refused': True}, 'loop': {'met': False}}
    bench.judge_refusal(record, None, {}, (0.95, 1.05))
    assert calls == [(1.0, 1.0), (0.95, 1.05)]
    assert record['truth_refuses'] is False and record['truth_refuses_like_for_like'] is True
    assert bench.refused_correctly(record, False) is False
    assert bench.refused_correctly(record, True) is True
    # a design with no doubt is judged once: both columns are the same design
    plain = {'nominal': {'refused': True}, 'loop': {'met': False}}
    bench.judge_refusal(plain, None, {}, (1.0, 1.0))
    assert calls[-1] == (1.0, 1.0) and len(calls) == 3 and plain['truth_refuses_like_for_like'] is False
    # a row from before s24 has no like-for-like judgement: the cell says so rather than counting it as wrong
    old = {'nominal': {'refused': True}, 'loop': {'met': False}, 'truth_refuses': True}
    assert bench.refused_correctly(old, True) is None
    assert bench._correct_refusals([record, plain, old]) == '1; 1 (+1 ?)'

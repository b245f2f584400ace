"""Which effect does the diagnosis name on random foreign logs, and is it the hidden one? (false and wrong names)

Each variant is :func:`aeropend_core.testing.foreign_logs.random_spec` (20-49 Hz, the current read in the PWM pulse,
period-averaged or absent, a one-sided or centred current ADC, counts / degrees / radians, host stamps with stalls,
device millis() or none; one hidden catalog effect, at 0.3-0.9 of its typical size, or none), written as a log with
its profile, imported, and diagnosed as ``aeropend diagnose`` does by default (every catalog candidate, drift test
and discovery on). Counted:

* clean variants: a named effect is a **false name** (the worst outcome: a confident wrong answer);
* variants with a hidden effect: the hidden one named (alone or among others, or in a confounded pair), another
  named instead (a **wrong name**), or nothing named.

Run:  nice -n 10 .venv/bin/python bench/foreign_naming.py --variants 40 --first 0 \
          --out bench/results/FOLDER/naming_0.json
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path


def outcome(spec) -> dict:
    import yaml

    from aeropend_core.diagnosis.diagnose import diagnose
    from aeropend_core.io.log_profile import import_log, load_profile
    from aeropend_core.io.recording import from_columns
    from aeropend_core.testing.foreign_logs import generate
    from aeropend_core.errors import AeropendError
    hidden = sorted(spec.effects)
    row = {'seed': spec.seed, 'rate_hz': round(spec.rate, 2), 'current': spec.current,
           'current_offset_counts': spec.current_offset_counts, 'stamps': spec.stamps, 'hidden': hidden,
           'duration_s': round(spec.duration, 1)}
    log = generate(spec)
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        (folder / 'log.csv').write_text(log.text)
        (folder / 'profile.yaml').write_text(yaml.safe_dump(log.profile))
        try:
            columns, _ = import_log(folder / 'log.csv', load_profile(folder / 'profile.yaml'))
            started = time.process_time()
            found = diagnose(from_columns(columns, source='log.csv'))
        except AeropendError as error:          # a refusal with its reason: an outcome, not a crash
            row.update(result='refused', why=str(error)[:200])
            return row
    named = [f.effect for f in found.found]
    together = set(named) | {other for f in found.found for other in f.confounded_with}
    if not hidden:
        result = 'false_name' if named else 'clean'
    elif set(hidden) & together:
        result = 'hidden_named'
    else:
        result = 'wrong_name' if named else 'nothing_named'
    row.update(result=result, verdict=found.verdict, named=named,
               confounded_with=[f.confounded_with for f in found.found],
               findings=sorted({f.code for f in found.findings}), cpu_seconds=round(time.process_time() - started, 1))
    return row


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--variants', type=int, default=40)
    parser.add_argument('--first', type=int, default=0)
    parser.add_argument('--out', type=Path, required=True)
    args = parser.parse_args()
    from threadpoolctl import threadpool_limits

    from aeropend_core.testing.foreign_logs import random_spec
    rows = []
    args.out.parent.mkdir(parents=True, exist_ok=True)
    for seed in range(args.first, args.first + args.variants):
        with threadpool_limits(1):
            row = outcome(random_spec(seed))
        rows.append(row)
        print(json.dumps(row), flush=True)
        counts = {}
        for r in rows:
            counts[r['result']] = counts.get(r['result'], 0) + 1
        args.out.write_text(json.dumps({'counts': counts, 'rows': rows}, indent=1))
    print(json.dumps(counts))
    return 0


if __name__ == '__main__':
    sys.exit(main())

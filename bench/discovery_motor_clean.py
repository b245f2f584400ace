"""The motor equation's search alone on clean records: does it propose a term where the motor has none?

Records: bench/false_alarms.py's (parameters +-25 %, LHC and staircase, PSNR 30-60 dB, 60 s), seeds BASE ..
BASE + COUNT - 1. Each is prepared as the diagnosis prepares it (motor observer) and searched by
:func:`aeropend_core.diagnosis.motor_discovery.discover_motor` exactly as ``aeropend diagnose`` runs it (the weak-form
screen as the gate, then the output-error proof). A false proposal = a proven motor term. The pendulum's part of the
diagnosis is not run here (bench/discovery.py --part clean runs the whole diagnosis; this is the cheaper check of the
motor search on more records).

Run:  nice -n 10 .venv/bin/python bench/discovery_motor_clean.py [--count 40] [--seed-base 64000] [--out FOLDER]
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0], allow_abbrev=False)
    parser.add_argument('--count', type=int, default=40, help='clean records (default 40)')
    parser.add_argument('--seed-base', type=int, default=64000, help='first seed (default 64000)')
    parser.add_argument('--out', default=str(ROOT / 'results' / '2026-11-27-s9-discover3'))
    args = parser.parse_args()
    from threadpoolctl import threadpool_limits

    from aeropend_core.diagnosis.compare import prepare
    from aeropend_core.diagnosis.motor_discovery import discover_motor
    from false_alarms import record
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    target = out / 'motor-clean.json'
    rows = []
    with threadpool_limits(1):
        for seed in range(args.seed_base, args.seed_base + args.count):
            recording, meta = record(seed)
            started = time.process_time()
            prep = prepare(recording)
            found = discover_motor(prep)
            best = found.terms[0] if found.terms else None
            row = {**meta, 'observer': prep.motor.kind if prep.motor is not None else 'inadequate',
                   'current_noise_mA': round(found.noise_rms * 1e3, 3), 'note': found.note,
                   'proposed': found.proven[0].term.expression if found.proven else None,
                   'best_candidate': best.term.expression if best else None,
                   'best_status': best.status if best else None, 'why_not': best.why_not if best else None,
                   'cpu_s': round(time.process_time() - started, 2)}
            rows.append(row)
            print(row, flush=True)
            proposed = sum(1 for r in rows if r['proposed'])
            target.write_text(json.dumps({'summary': {'records': len(rows), 'proposing_a_motor_term': proposed,
                                                      'screen_passed': sum(1 for r in rows if r['best_candidate'])},
                                          'rows': rows}, indent=1))
    return 0


if __name__ == '__main__':
    sys.exit(main())

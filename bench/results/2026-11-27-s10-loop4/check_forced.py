"""Does a long designed record decide thrust_lag vs angle_filter at 40 dB when the loop's early end is overruled?

The loop of bench/experiment_decide.py (--part loop, lag 20 ms, seed 26400, 40 dB) ends at once with "cannot decide
within the budget: no duration decides" (the design's separation is below the diagnosis's materiality floor). Here
the same first record and the same design are played anyway, repeated to 300 s, and both records are diagnosed
together: the verdict and the held-out evidence of the pair (the gain of adding the rival, in noise RMS units).

    nice -n 10 python bench/results/2026-11-27-s10-loop4/check_forced.py
"""
from __future__ import annotations

import json
import math
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from experiment_decide import stream_record  # noqa: E402

from aeropend_core.diagnosis.experiment_design import confounded_models, design_experiment  # noqa: E402
from aeropend_core.diagnosis.experiment_loop import diagnose_records  # noqa: E402
from aeropend_core.present.verdict_text import verdict_of  # noqa: E402
from aeropend_core.sim.excitation import lhc_schedule  # noqa: E402

SEED, TRUTH, PSNR, REPEATS = 26400, {'thrust_lag': 0.02}, 40.0, 10
started = time.process_time()
first = stream_record(lhc_schedule(40.0, duty_range=(0.0, 0.7), duty_cap=0.7, seed=SEED).duty(duration=40.0),
                      TRUTH, PSNR, SEED + 100, 'round 1')
diagnosis = diagnose_records([first], {'drift': False})
print('first:', diagnosis.verdict, verdict_of(diagnosis), flush=True)
design = design_experiment(confounded_models(diagnosis), diagnosis.noise_rms, duration=30.0, candidates=30,
                           refinements=15, seed=SEED + 1, original_duty_limit=0.7)
print('design:', design.describe(), flush=True)
long = design.repeated(REPEATS)
second = stream_record(long.schedule.duty(), TRUTH, PSNR, SEED + 200, 'round 2')
joint = diagnose_records([first, second], {'drift': False})
found = [{'effect': f.effect, 'confounded_with': f.confounded_with, 'parameters': f.parameters,
          'standard_errors': f.standard_errors} for f in joint.found]
result = {'truth': TRUTH, 'seed': SEED, 'psnr_db': PSNR, 'played_seconds': long.schedule.duration,
          'predicted_separation_noise_rms': design.separation, 'seconds_to_decide': design.seconds_to_decide,
          'joint_verdict': joint.verdict, 'message': verdict_of(joint), 'found': found,
          'candidates': [{'effect': c.effect, 'significant': c.significant, 'delta_bic': c.delta_bic,
                          'dm': getattr(c, 'dm_statistic', math.nan)} for c in joint.candidates],
          'cpu_seconds': time.process_time() - started}
print(json.dumps(result, default=str, indent=1), flush=True)
(Path(__file__).parent / 'check_forced.json').write_text(json.dumps(result, default=str, indent=1) + '\n')

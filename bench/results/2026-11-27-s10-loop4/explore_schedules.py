"""Faster separators for thrust_lag vs angle_filter at 20 ms? Predicted separation (noise RMS units at 40 dB, both
models at the simulator's parameters, no parameter draws) of 30 s schedules: full-range square waves 0.2-0.7 Hz, a
sweep, steps with rests, a narrower square.

    nice -n 10 python bench/results/2026-11-27-s10-loop4/explore_schedules.py
"""
import math
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from experiment_decide import NOISE, true_model  # noqa: E402

from aeropend_core.diagnosis.experiment_design import Block, DutySchedule, predict_separation  # noqa: E402

d = 0.02
models = [true_model('thrust_lag', {'time_constant': d}), true_model('angle_filter', {'filter_delay': d})]
cands = {}
for hz in (0.2, 0.3, 0.4, 0.5, 0.7):
    cands[f'square 0-0.7 {hz} Hz'] = (Block('rest', 1.0), Block('square', 29.0, 0.35, 0.35, hz, hz))
cands['sweep 0-0.7 0.3-3 Hz'] = (Block('rest', 1.0), Block('sweep', 29.0, 0.35, 0.35, 0.3, 3.0))
cands['steps 0.7/rest 2.9 s'] = (Block('rest', 1.0),) + tuple(
    b for _ in range(5) for b in (Block('step', 2.9, level=0.7), Block('rest', 2.9)))
cands['square 0.2-0.7 0.4 Hz'] = (Block('rest', 1.0), Block('square', 29.0, 0.45, 0.25, 0.4, 0.4))
for name, blocks in cands.items():
    t = time.process_time()
    s = predict_separation(models, DutySchedule(blocks).duty(), NOISE[40.0], draws=0)
    print(f'{name:28s} sep {s["separation"]:.4f} train {s["separation_train"]:.4f} held '
          f'{s["separation_heldout"]:.4f} peak {s["peak"]:.3f} maxdeg {math.degrees(s["max_angle"]):.0f} '
          f'cpu {time.process_time() - t:.1f}', flush=True)

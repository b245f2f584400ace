"""Where a cProfile of ``aeropend diagnose`` spends its time: the cumulative seconds of chosen functions (the parts
of issue 41's table), one column per profile file. The parts nest (an indented row is inside the row above it).

Make a profile (one worker: cProfile sees only the main thread):
    AEROPEND_WORKERS=1 .venv/bin/python -m cProfile -o prof.out .venv/bin/aeropend diagnose rec.csv --quiet
Run:  .venv/bin/python bench/profile_parts.py prof_before.out prof_after.out
"""
import pstats
import sys

ROWS = [
    ('whole process', None, '<module>', 'bin/aeropend'),
    ('argument parsing', 'cli/__init__.py', 'parse_arguments', None),
    ('loading + quality gate', 'cli/_checks.py', 'load_for_analysis', None),
    ('  quality gate (check_recording)', 'signals/quality.py', 'check_recording', None),
    ('  scipy.signal import (inside the gate)', 'scipy/signal/__init__.py', '<module>', None),
    ('  outlier check (running median)', 'signals/quality_checks.py', '_check_outliers', None),
    ('prepare stage (motor observer, ensemble)', 'diagnosis/stages.py', 'prepare_stage', None),
    ('  motor observer fit', 'signals/motor.py', 'fit_motor', None),
    ('  back-EMF ensemble', 'signals/motor.py', 'back_emf_ensemble', None),
    ('compare stage', 'diagnosis/stages.py', 'compare_stage', None),
    ('catalog search (7 candidates)', 'diagnosis/stages.py', 'catalog_stage', None),
    ('  lag/offset basin search', 'diagnosis/basins.py', 'search_lag_basins', None),
    ('  dead-zone threshold profile', 'diagnosis/threshold_profile.py', 'threshold_profile', None),
    ('friction-law doubt refits', 'diagnosis/diagnose.py', '_widen_for_friction_shape', None),
    ('discovery stage', 'diagnosis/stages.py', 'discovery_stage', None),
    ('drift stage', 'diagnosis/stages.py', 'drift_stage', None),
    ('state map', 'diagnosis/state_map.py', 'state_map', None),
    ('JSON output', 'present/json_output.py', 'write_json', None),
    ('all output-error fits (44)', 'diagnosis/output_error.py', 'fit_output_error', None),
    ('  simulation kernel', 'diagnosis/output_error.py', '_simulate_kernel', None),
    ('  sensitivity kernel', 'diagnosis/sensitivity.py', 'sensitivity_kernel', None),
    ('  Jacobians (all)', 'diagnosis/output_error.py', 'jacobian', None),
    ('  input-ensemble covariance', 'diagnosis/output_error.py', 'change', None),
    ('  trust-region SVDs', 'linalg/_decomp_svd.py', 'svd', None),
]


def cumulative(stats, suffix, name):
    return sum(v[3] for (f, _, n), v in stats.items() if f.endswith(suffix) and n == name)


def main(paths):
    stats = [pstats.Stats(p).stats for p in paths]
    print('| part | ' + ' | '.join(paths) + ' |')
    print('| --- |' + ' --- |' * len(paths))
    for label, suffix, name, alt in ROWS:
        values = [cumulative(s, suffix or alt, name) for s in stats]
        print(f'| {label} | ' + ' | '.join(f'{v:.2f}' for v in values) + ' |')


main(sys.argv[1:])

# ruff: noqa: E402
"""Session 21: bench/second_rig.py with the motor observer's rule before session 21 (no fallback margin: dropped
whenever the current's error exceeds 1.5x its noise), for before/after rows on the same seeds. Run from the root:
.venv/bin/python bench/results/2026-12-07-s21-observer/probes/old_rule.py [bench/second_rig.py's arguments]"""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[3]))
from aeropend_core.signals import motor

motor.FALLBACK_MARGIN = 0.0
import second_rig

second_rig.main()

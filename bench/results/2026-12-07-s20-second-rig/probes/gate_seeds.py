# ruff: noqa: E501, E702
"""Development probe of session 20 (bench/results/2026-12-07-s20-second-rig/README.md); run from the tree root."""
import sys
sys.path.insert(0, str(__import__('pathlib').Path(__file__).resolve().parents[3]))
import second_rig as sr
from aeropend_core.signals.quality import check_recording
from aeropend_core.errors import AeropendError
for arg in sys.argv[1:]:
    seed, _, exc = arg.partition(':')
    rec, rig = sr.record(int(seed), exc or 'mixed')
    try:
        rep = check_recording(rec)
        print(arg, 'passes;', [(f.code, f.severity) for f in rep.findings])
    except AeropendError as e:
        print(arg, 'REFUSED', str(e)[:150])

"""How accurate the diagnosis's nominal parameters were measured to be at each sample rate: a leaf module.

Measured constants only (as mcap's ``well_known.py``), read by the data-quality gate
(:mod:`aeropend_core.signals.quality_checks`, which refuses a rate slower than the slowest measured) and by the
diagnosis's doubts (:func:`aeropend_core.diagnosis.doubts.rate_doubts`, which says them beside the numbers).
"""
from __future__ import annotations

#: Largest |relative error| of diagnose's nominal parameters measured per sample rate [Hz] on seeded simulations
#: (bench/lowrate_accuracy.py: default rig, 40 dB, 10-bit, 30 s, 4 seeds; bench/results/2026-11-27-lowrate), and
#: the tolerance the rate is held to (damping and gravity_stiffness; thrust_gain twice it).
RATE_ACCURACY = (
    (98.0, {'gravity_stiffness': 0.049, 'damping': 0.014, 'thrust_gain': 0.058}, 0.10),
    (49.0, {'gravity_stiffness': 0.037, 'damping': 0.021, 'thrust_gain': 0.043}, 0.15),
    (24.5, {'gravity_stiffness': 0.103, 'damping': 0.066, 'thrust_gain': 0.127}, 0.25),
)

__all__ = ['RATE_ACCURACY']

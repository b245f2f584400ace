"""Share of white-noise draws in which the diagnosis's Diebold--Mariano test decides at the design's evidence.

    python bench/results/2026-11-27-s11-suite/power_check.py

Held-out evidence sum((separation / noise)^2) = DECISIVE_EVIDENCE, the wrong model's error = noise + separation, the
right one's = noise; decided when aeropend_core.diagnosis.evidence.diebold_mariano >= DM_THRESHOLD. 400 draws per
case (binomial 1 sigma 1.5 %).
"""
from __future__ import annotations

import math

import numpy as np

from aeropend_core.diagnosis.evidence import diebold_mariano
from aeropend_core.diagnosis.experiment_design import DECISIVE_EVIDENCE, DM_THRESHOLD


def main() -> None:
    rng = np.random.default_rng(1)
    print(f'evidence {DECISIVE_EVIDENCE:.1f}, threshold {DM_THRESHOLD}')
    for samples in (2450, 12000):
        time = np.arange(samples) * 0.00204
        shapes = {'constant': np.ones(samples), 'sine 0.3 Hz': np.sin(2 * np.pi * 0.3 * time),
                  'steps': np.sign(np.sin(2 * np.pi * 0.2 * time)) * (1 + 0.5 * np.sin(2 * np.pi * 0.05 * time))}
        for name, shape in shapes.items():
            separation = shape / np.sqrt(np.mean(shape ** 2)) * math.sqrt(DECISIVE_EVIDENCE / samples)
            decided = np.mean([diebold_mariano(noise + separation, noise)[0] >= DM_THRESHOLD
                               for noise in rng.standard_normal((400, samples))])
            print(f'{name:12s} {samples:6d} samples: decided in {decided:.3f} of 400 draws')


if __name__ == '__main__':
    main()

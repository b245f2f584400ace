"""Generate bags/exercise.csv: a 60 s rig-like recording with hidden physics for the diagnosis walkthrough.

SPOILER: the hidden truth is written here and nowhere else. Run `aeropend diagnose bags/exercise.csv` first.

Run from the repository root:  .venv/bin/python bags/make_exercise.py
"""
from pathlib import Path

from aeropend_core.cli.simulate import write_csv
from aeropend_core.excitation import lhc_schedule
from aeropend_core.model import DEFAULT_PARAMETERS
from aeropend_core.noise import MeasurementNoise
from aeropend_core.simulate import simulate

DURATION = 60.0          # s
SEED = 2026
# The hidden truth: two effects, so the loop needs two rounds; nominal parameters moved away from the defaults.
HIDDEN_EFFECTS = {'thrust_lag': {'time_constant': 0.12}, 'coulomb_friction': {'friction_acceleration': 3.0}}
PARAMETERS = DEFAULT_PARAMETERS.scaled(damping=1.15, thrust_coefficient=0.9, armature_resistance=1.1)


def main() -> None:
    duty = lhc_schedule(DURATION, seed=SEED).duty(duration=DURATION)
    trajectory = simulate(duty, parameters=PARAMETERS, effects=HIDDEN_EFFECTS,
                          noise=MeasurementNoise(psnr_db=40.0, quantise=True), seed=SEED)
    target = Path(__file__).with_name('exercise.csv')
    write_csv(str(target), trajectory.columns(with_truth=False))
    print(f'wrote {target} ({len(trajectory)} samples)')


if __name__ == '__main__':
    main()

"""Check the hypothesis: seed 9113's joint 'unexplained' comes from records with different noise levels."""
# Run: nice -n 10 python bench/results/2026-11-27-experiment/check_equal_noise.py (about 3 min of CPU)
from aeropend_core.diagnosis.experiment_design import steps_to_duty
from aeropend_core.diagnosis.joint import diagnose_joint
from aeropend_core.io.recording import from_columns
from aeropend_core.present.verdict_text import verdict_of
from aeropend_core.sim.excitation import lhc_schedule
from aeropend_core.sim.noise import MeasurementNoise
from aeropend_core.sim.simulate import RigSimulator
# the bench stores the blocks, not the steps: the design is made again from the same seed (deterministic)
from aeropend_core.diagnosis.compare import prepare
from aeropend_core.diagnosis.experiment_design import competing_models, design_experiment
from aeropend_core.sim.simulate import simulate
truth = {'angle_offset': 0.02}
seed = 9113
duty = lhc_schedule(60.0, duty_range=(0.0, 0.3), duty_cap=0.3, seed=seed).duty(duration=60.0)
first_noisy = simulate(duty, effects=truth, noise=MeasurementNoise(40.0, True), seed=seed + 1)
prep = prepare(from_columns(first_noisy.columns(with_truth=False)))
models = competing_models(prep, [('angle_offset',), ('cable_torque',)])
design = design_experiment(models, prep.noise_rms, duration=30.0, duty_limit=0.7, candidates=30, refinements=15,
                           seed=seed, original_duty_limit=0.3)
print([b.text() for b in design.schedule.blocks], flush=True)
played = steps_to_duty(design.schedule.steps)
def stream(d, s):   # the same absolute noise in both records (fixed full-scale peaks, as a rig's ADC)
    sim = RigSimulator(effects=truth, noise=MeasurementNoise(40.0, True), seed=s)
    return from_columns(sim.run(d).columns(with_truth=False))
a, b = stream(duty, seed + 1), stream(played, seed + 2)
j = diagnose_joint([a, b], drift=False)
print('equal absolute noise:', j.verdict, verdict_of(j), flush=True)

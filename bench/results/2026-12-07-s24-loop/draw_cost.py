"""Per draw of `control check`'s settling range on the s21 62 s record: the closed loop vs its schedule metrics."""
import time

from aeropend_core.control.controller_file import Controller
from aeropend_core.control.loop import FeedforwardMap, feedforward_per_sample, simulate_loop
from aeropend_core.control.metrics import schedule_metrics
from aeropend_core.control.record import load_closed_loop
from aeropend_core.sim.noise import MeasurementNoise

data = load_closed_loop('/tmp/loopdev/speed/bags/aeropend_20261207_065523')
controller = Controller.load('bench/results/2026-12-07-s21-control-speed/gains.yaml')
schedule = data.schedule
n = int(round(schedule.duration * 490))
reference = schedule.reference(n, 1 / 490)
feedforward = feedforward_per_sample(FeedforwardMap(controller.parameters, controller.effects), reference)
noise = MeasurementNoise(psnr_db=40, quantise=True, signals=('angle',))


def draw(seed):
    return simulate_loop(controller.gains, reference, feedforward, controller.parameters, controller.effects, noise,
                         seed, duty_limit=0.8)


draw(0)
for seed in range(3):
    started = time.perf_counter()
    run = draw(seed)
    simulated = time.perf_counter()
    schedule_metrics(run.time, run.angle, run.duty, schedule)
    print(n, 'sim', round(simulated - started, 4), 'metrics', round(time.perf_counter() - simulated, 4))

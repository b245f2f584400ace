"""In-process CPU (all threads) of load_closed_loop + check_record on the s21 62 s record, warm, 5 runs each; run
with PYTHONPATH=TREE for a base tree. Less sensitive to the machine's load than `control_speed.py`'s wall."""
import time

from aeropend_core.control.check import check_record
from aeropend_core.control.controller_file import Controller
from aeropend_core.control.record import load_closed_loop

BAG = '/tmp/loopdev/speed/bags/aeropend_20261207_065523'
controller = Controller.load('bench/results/2026-12-07-s21-control-speed/gains.yaml')


def once():
    data = load_closed_loop(BAG)
    return check_record(data.time, data.angle, data.duty, controller, data.schedule)


once()
loads, checks = [], []
for _ in range(5):
    started = time.process_time()
    data = load_closed_loop(BAG)
    loaded = time.process_time()
    check_record(data.time, data.angle, data.duty, controller, data.schedule)
    loads.append(loaded - started)
    checks.append(time.process_time() - loaded)
print('load_closed_loop CPU s', sorted(round(t, 3) for t in loads))
print('check_record CPU s', sorted(round(t, 3) for t in checks))

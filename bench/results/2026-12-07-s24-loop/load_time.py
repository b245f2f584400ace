"""In-process CPU of load_closed_loop on the s21 62 s record, warm, 5 runs (run with PYTHONPATH=TREE for a base)."""
import time

import aeropend_core.control.record as record

BAG = '/tmp/loopdev/speed/bags/aeropend_20261207_065523'
print(record.__file__)
record.load_closed_loop(BAG)
times = []
for _ in range(5):
    started = time.process_time()
    record.load_closed_loop(BAG)
    times.append(time.process_time() - started)
print(sorted(times))

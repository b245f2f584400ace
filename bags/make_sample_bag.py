"""Generate bags/sample_sim/: a short MCAP bag recorded by recorder_node from sim_node driven by excitation_node.

Three real processes over DDS (local discovery), exactly as a user would run them: the sim (with a hidden Coulomb
friction and 40 dB noise), a 12 s Latin-hypercube excitation, and the recorder. Open the result in Foxglove
(bags/sample_sim/sample_sim_0.mcap) or read it with `aeropend_core.io.bag.read_samples('bags/sample_sim')`.

Run from the repository root:  .venv/bin/python bags/make_sample_bag.py
"""
from __future__ import annotations

import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from aeropend_ros._ros_env import local_ros_environment

TARGET = ROOT / 'bags' / 'sample_sim'
SCHEDULE_SECONDS = 12.0


def start(module: str, *params: str, env: dict) -> subprocess.Popen:
    args = [sys.executable, '-m', f'aeropend_ros.{module}', '--ros-args']
    for param in params:
        args += ['-p', param]
    return subprocess.Popen(args, cwd=ROOT, env=env)


def main() -> int:
    if TARGET.exists():
        shutil.rmtree(TARGET)
    env = local_ros_environment(domain_id=77)
    recorder = start('recorder_node', f'output:={TARGET}', 'chunk_size:=65536', env=env)
    sim = start('sim_node', 'effects:=[coulomb_friction=3.0]', 'psnr_db:=40.0', 'seed:=7', env=env)
    excitation = start('excitation_node', f'duration:={SCHEDULE_SECONDS}', 'seed:=7', 'exit_when_done:=true',
                       env=env)
    try:
        excitation.wait(timeout=SCHEDULE_SECONDS + 60)    # it exits once the schedule is over and duty is 0 again
        time.sleep(1.0)                                    # one more second of rest at duty 0 in the bag
    finally:
        for process in (recorder, sim, excitation):
            if process.poll() is None:
                process.send_signal(signal.SIGINT)
        for process in (recorder, sim, excitation):
            try:
                process.wait(timeout=20)
            except subprocess.TimeoutExpired:
                process.kill()
    from aeropend_core.io.bag import bag_topics, read_samples
    samples = read_samples(TARGET)
    print(f'wrote {TARGET}: {len(samples["time"])} samples over {samples["time"][-1]:.1f} s, topics '
          f'{sorted(bag_topics(TARGET))}')
    return 0


if __name__ == '__main__':
    sys.exit(main())

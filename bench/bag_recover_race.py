"""``bag-recover --in-place`` racing a recorder that is starting on the same folder: recordings lost out of N.

One ``sim_node`` publishes samples on a private ROS domain; each trial starts a ``recorder_node`` on a fresh
folder while this process calls ``recover_bag(folder, in_place=True)`` in a tight loop from before the folder
exists until the recorder has written for ``--record-seconds``; the recorder is then stopped with Ctrl-C
(:func:`aeropend_ros.testing.recover_race`). A recording is lost when its bag is unreadable, empty, or holds fewer
samples than its metadata.yaml says. (The reliability round found 3 of 30 lost with the PID-file lock.)

Usage::

    nice -n 10 .venv/bin/python bench/bag_recover_race.py --trials 30
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from aeropend_ros._ros_env import ensure_ros_environment  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0], allow_abbrev=False)
    parser.add_argument('--trials', type=int, default=30)
    parser.add_argument('--record-seconds', type=float, default=1.0, help='recording after the race [s]')
    args = parser.parse_args(argv)
    ensure_ros_environment(local_only=True)
    import subprocess

    from aeropend_ros._ros_env import local_ros_environment
    from aeropend_ros.testing import private_domain_id, recover_race
    domain = private_domain_id()
    started = time.perf_counter()
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        sim = subprocess.Popen([sys.executable, '-m', 'aeropend_ros.sim_node', '--ros-args', '-p', 'psnr_db:=40.0'],
                               env=local_ros_environment(domain_id=domain), stdout=subprocess.DEVNULL,
                               stderr=subprocess.DEVNULL, cwd=ROOT)
        try:
            for trial in range(args.trials):
                result = recover_race(Path(tmp) / f'race_{trial}', domain, record_seconds=args.record_seconds)
                results.append(result)
                print(f'trial {trial}: lost={result["lost"]} recorded={result["recorded"]} read={result["read"]} '
                      f'recover calls {result["outcomes"]}', flush=True)
        finally:
            sim.send_signal(2)
            sim.wait(30)
    outcomes: Counter = Counter()
    for r in results:
        outcomes.update(r['outcomes'])
    summary = {'trials': len(results), 'recordings_lost': sum(r['lost'] for r in results),
               'recover_calls': dict(outcomes), 'samples_recorded': sum(r['recorded'] for r in results),
               'seconds': round(time.perf_counter() - started, 1)}
    print(json.dumps(summary, indent=1))
    return 1 if summary['recordings_lost'] else 0


if __name__ == '__main__':
    sys.exit(main())

"""Helpers for running real ROS 2 nodes in tests and benchmarks: a private ROS_DOMAIN_ID, an rclpy context of one's own.

Shipped with the package (the load test in bench/ uses them too); importing this module imports no rclpy until a
helper is called.
"""
from __future__ import annotations

import contextlib
import os
import random
import signal
import subprocess
import time

from aeropend_ros._ros_env import ensure_ros_environment


def interrupt(process: subprocess.Popen, timeout: float = 30.0) -> int:
    """Stop a child process as a user would: SIGINT (Ctrl-C), SIGKILL if it has not ended after ``timeout`` [s].

    Returns its exit status (negative: ended by that signal).
    """
    if process.poll() is None:
        process.send_signal(signal.SIGINT)
        try:
            process.wait(timeout)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
    return process.returncode


#: Domains handed out in this process (never twice).
_USED_DOMAINS: set[int] = set()


def private_domain_id(probe_seconds: float = 1.0) -> int:
    """A ROS_DOMAIN_ID (1..100) that nobody else on this machine is using right now.

    Random candidates are probed: a throw-away node joins the domain and watches the ROS graph for
    `probe_seconds`; the first domain where no other node shows up is taken. Several test runs share this
    machine, and two sims on one domain would interleave their samples.
    """
    rng = random.Random(os.getpid() * 7919 + time.monotonic_ns())
    candidates = [d for d in rng.sample(range(1, 101), 100) if d not in _USED_DOMAINS]
    chosen = candidates[0]
    for domain_id in candidates[:10]:
        if _domain_is_quiet(domain_id, probe_seconds):
            chosen = domain_id
            break
    _USED_DOMAINS.add(chosen)
    return chosen


def _domain_is_quiet(domain_id: int, seconds: float) -> bool:
    """True when no other ROS node appears on `domain_id` within `seconds` (local discovery)."""
    ensure_ros_environment(local_only=True)
    import rclpy
    with own_context(domain_id) as context:
        node = rclpy.create_node('domain_probe', context=context)
        try:
            deadline = time.monotonic() + seconds
            while time.monotonic() < deadline:
                if len(node.get_node_names()) > 1:
                    return False
                time.sleep(0.05)
            return True
        finally:
            node.destroy_node()


@contextlib.contextmanager
def own_context(domain_id: int):
    """An rclpy context of its own on `domain_id` (tests never touch the global one), shut down on exit."""
    import rclpy
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain_id)
    try:
        yield context
    finally:
        rclpy.try_shutdown(context=context)


def recover_race(folder, domain_id: int, record_seconds: float = 2.0, timeout: float = 60.0) -> dict:
    """One race of ``bag-recover --in-place`` against a recorder that is starting on ``folder``.

    A ``recorder_node`` (its own process, only ``/aeropend/samples``, 16 KiB chunks) is started on ``folder``
    while this process calls :func:`aeropend_core.io.bag_recover.recover_bag` on the same folder with
    ``in_place=True`` in a tight loop, from before the folder exists until the recorder has been writing for
    ``record_seconds`` [s]. Then the recorder is stopped with SIGINT. A publisher of samples (a ``sim_node``) must be
    running on ``domain_id``.

    Returns
    -------
    dict
        ``attempts`` and ``outcomes`` of the recover calls (error kind -> count), ``recorded`` (messages
        metadata.yaml says), ``read`` (samples read back with ``on_incomplete='raise'``), ``lost`` (True when the
        bag is unreadable, empty or holds fewer samples than metadata.yaml says), ``recorder_output``.
    """
    import subprocess
    import sys
    import tempfile
    import threading
    from pathlib import Path

    import yaml

    from aeropend_core.errors import AeropendError
    from aeropend_core.io.bag import read_samples
    from aeropend_core.io.bag_recover import recover_bag
    from aeropend_ros._ros_env import local_ros_environment
    folder = Path(folder)
    outcomes: dict[str, int] = {}
    stop = threading.Event()

    def hammer() -> None:
        while not stop.is_set():
            try:
                recover_bag(folder, in_place=True)
                kind = 'repaired'
            except AeropendError as error:
                text = str(error)
                kind = ('refused: being written' if 'being written' in text else 'no bag yet'
                        if 'does not exist' in text or 'no .mcap' in text else f'other: {text[:80]}')
            outcomes[kind] = outcomes.get(kind, 0) + 1
            time.sleep(0.002)

    log = tempfile.NamedTemporaryFile('w+', prefix='race_recorder_', suffix='.log', delete=False)  # noqa: SIM115
    thread = threading.Thread(target=hammer, daemon=True)
    thread.start()
    recorder = subprocess.Popen(
        [sys.executable, '-m', 'aeropend_ros.recorder_node', '--ros-args', '-p', f'output:={folder}',
         '-p', 'chunk_size:=16384', '-p', "topics:=['/aeropend/samples']", '-p', 'include_regex:=^/aeropend/samples$'],
        env=local_ros_environment(domain_id=domain_id), stdout=log, stderr=subprocess.STDOUT)
    try:
        deadline = time.monotonic() + timeout
        files = []
        while time.monotonic() < deadline and recorder.poll() is None:   # wait for samples on disk
            files = list(folder.glob('*.mcap')) if folder.is_dir() else []
            if files and files[0].stat().st_size > 64 * 1024:
                break
            time.sleep(0.02)
        time.sleep(record_seconds)          # record for a while (the race is over: the recorder writes)
    finally:
        stop.set()
        thread.join(30)
        interrupt(recorder)
        log.flush()
        output = Path(log.name).read_text(errors='replace')
        log.close()
    result = {'attempts': sum(outcomes.values()), 'outcomes': outcomes, 'recorder_output': output[-2000:],
              'recorded': 0, 'read': 0, 'lost': True}
    try:
        info = yaml.safe_load((folder / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
        result['recorded'] = int(info['message_count'])
        result['read'] = len(read_samples(folder, on_incomplete='raise')['sequence'])
        result['lost'] = result['read'] == 0 or result['read'] != result['recorded']
    except (OSError, KeyError, TypeError, AeropendError, yaml.YAMLError) as error:
        result['error'] = str(error)
    return result


__all__ = ['own_context', 'private_domain_id', 'recover_race']

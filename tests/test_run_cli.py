"""`aeropend run` end to end (short, faster than real time) with `aeropend monitor` watching, and the CLI's errors."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from aeropend_ros._ros_env import local_ros_environment
from aeropend_ros.cli.monitor import DriftTracker
from tests.ros_helpers import ROOT, private_domain_id

AEROPEND = [sys.executable, '-c', 'import sys; from aeropend_core.cli import main; sys.exit(main())']


def run_cli(arguments, env, timeout=120.0):
    return subprocess.run(AEROPEND + arguments, env=env, cwd=ROOT, capture_output=True, text=True, timeout=timeout)


@pytest.mark.timeout(300)
def test_run_records_identifies_and_diagnoses(tmp_path):
    """30 s of the default sim (hidden angle offset) in real time: bag complete, windows identified, offset
    diagnosed. Real time, not faster: the identification's worker process may take tens of seconds to start on a
    loaded machine, and windows due before it is up are skipped (said), so a 15 s run could end with none."""
    env = local_ros_environment(domain_id=private_domain_id())
    run = subprocess.Popen(AEROPEND + ['run', '--duration', '30', '--realtime-factor', '1', '--record',
                                       str(tmp_path), '--window', '12', '--hop', '3',
                                       '--json', str(tmp_path / 'run.json'), '--report', str(tmp_path / 'r.html')],
                           env=env, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        monitor = run_cli(['monitor', '--once', '--timeout', '120'], env, timeout=150)
        output, _ = run.communicate(timeout=200)
    finally:
        if run.poll() is None:
            run.kill()
    assert run.returncode == 0, output
    assert 'Traceback' not in output, output
    # An open-loop run has no controller configuration to say: no topic the recorder refuses (it logged an ERROR
    # for aeropend/controller, advertised by the sim node in every mode, until 2026-12-07)
    assert 'not recording' not in output and '[ERROR]' not in output, output
    # The monitor saw a window of the running graph.
    assert monitor.returncode == 0, monitor.stderr + monitor.stdout
    assert 'held-out fit' in monitor.stdout and 'gravity_stiffness' in monitor.stdout
    assert 'sin(angle)' in monitor.stdout
    # Live windows were reported while running: a buffering line first, then one line per window (each span once,
    # a skipped window too), each published window with its data state; and the samples the node received.
    import re
    assert re.search(r'buffering \d+/12 s of samples for the first window', output), output
    windows = re.findall(r'^  window +([\d.]+)- *([\d.]+) s: (.*)$', output, flags=re.MULTILINE)
    assert windows, output
    spans = [(start, stop) for start, stop, _ in windows]
    assert len(spans) == len(set(spans)), output
    published = [text for _, _, text in windows if 'held-out fit' in text]
    assert published and all(text.endswith('data clean') or 'data FLAGGED: ' in text for text in published), output
    assert re.search(r'identification node: received \d+ of 14700 samples published \(\d+ lost in gaps', output), output
    # The bag holds every sample: continuous sequence, Ts spacing, 30 s.
    folders = [p for p in tmp_path.iterdir() if p.is_dir()]
    assert len(folders) == 1 and (folders[0] / 'metadata.yaml').exists(), output
    from aeropend_core.io.bag import read_samples
    samples = read_samples(folders[0])
    sequence = samples['sequence']
    assert sequence.size == round(30 * 490) and np.all(np.diff(sequence) == 1)
    assert np.allclose(np.diff(samples['time']), 1 / 490, atol=1e-8)
    assert set(np.unique(np.round(samples['duty'], 6))) > {0.0}, 'the excitation drove the sim'
    # The diagnosis at the end names the hidden effect (the default sim hides a 0.05 rad sensor offset).
    assert 'Diagnosis of 14700 samples' in output
    assert 'missing effect: angle_offset' in output, output
    # --json and --report: the same diagnosis, machine-readable and as a page; then the next step to take.
    import json
    summary = json.loads((tmp_path / 'run.json').read_text())
    assert summary['samples'] == 14700 and summary['diagnosis']['missing_effect'] == 'angle_offset'
    assert summary['schema'] == 'aeropend.run/1' and summary['diagnosis']['schema'] == 'aeropend.diagnosis/1'
    # the diagnosis is also kept beside the bag (JSON and report), the bag folder left as recorded
    saved = json.loads((tmp_path / f'{folders[0].name}.diagnosis.json').read_text())
    assert saved['missing_effect'] == 'angle_offset' and saved['schema'] == 'aeropend.diagnosis/1'
    assert (tmp_path / f'{folders[0].name}.report.html').stat().st_size > 10_000
    assert f'saved beside the bag: {folders[0]}.diagnosis.json' in output, output
    assert 'schedule_incomplete' not in output              # a whole run is not called cut short
    assert (tmp_path / 'r.html').stat().st_size > 10_000
    assert 'Next: add it and watch the error fall: aeropend diagnose' in output and '--add angle_offset' in output


def test_run_with_missing_port_fails_clearly():
    env = local_ros_environment(domain_id=private_domain_id())
    result = run_cli(['run', '--port', '/dev/ttyACM_does_not_exist'], env, timeout=60)
    assert result.returncode == 2
    assert 'does not exist' in result.stderr and 'Traceback' not in result.stderr


def test_run_with_unknown_effect_fails_clearly():
    env = local_ros_environment(domain_id=private_domain_id())
    result = run_cli(['run', '--effect', 'warp_drive=1'], env, timeout=60)
    assert result.returncode == 2
    assert 'unknown effect' in result.stderr and 'coulomb_friction' in result.stderr
    result = run_cli(['run', '--model-effect', 'coulomb_friction=4'], env, timeout=60)
    assert result.returncode == 2 and 'names only' in result.stderr


@pytest.mark.parametrize('arguments, message', [
    (['--duration', '10'], 'too short for the diagnosis'),
    (['--add', 'coulomb_friction=4'], 'names only'),
    (['--no-diagnose', '--json', '-'], 'cannot be used with --no-diagnose'),
    (['--report', '/no/such/folder/report.html'], 'does not exist'),
    (['--calibration', '/no/such/calibration.yaml'], 'cannot read the calibration file'),
    (['--calibration', 'config/serial_bridge_node.yaml', '--add', 'angle_filter'], 'fixed by --calibration'),
])
def test_run_refuses_arguments_that_cannot_work_before_starting(arguments, message):
    """Exit 2 with one line, before any node starts (no 'aeropend run: simulator' banner)."""
    result = run_cli(['run', *arguments], local_ros_environment(domain_id=private_domain_id()), timeout=60)
    assert result.returncode == 2, result.stdout + result.stderr
    assert message in result.stderr and 'Traceback' not in result.stderr
    assert 'aeropend run: simulator' not in result.stdout + result.stderr       # the banner is progress: stderr


def test_monitor_without_identification_says_so():
    env = local_ros_environment(domain_id=private_domain_id())
    result = run_cli(['monitor', '--once', '--timeout', '2'], env, timeout=60)
    assert result.returncode == 1
    assert 'no identification result' in result.stderr


def test_drift_tracker_flags_a_jump_and_restarts_on_model_change():
    tracker = DriftTracker(sigma=3.0, min_windows=3)
    for value in (10.0, 10.1, 9.9, 10.0):
        report = tracker.update({'damping': (value, 0.2)})
        assert not report['damping'][2]
    report = tracker.update({'damping': (11.5, 0.2)})           # 7.5 sigma above the running mean 10.0
    assert report['damping'][2] and report['damping'][1] == pytest.approx(7.5)
    report = tracker.update({'damping': (11.5, 0.2), 'angle_offset': (0.05, 0.001)})   # effect added: restart
    assert not any(flag for _, _, flag in report.values())
    assert Path(ROOT / 'aeropend_ros' / 'cli' / 'monitor.py').exists()


@pytest.mark.timeout(180)
def test_run_on_the_rig_through_the_serial_bridge(tmp_path):
    """`aeropend run --port` against the device emulator (a fake rig on a pty): bridge, excitation, recorder,
    identification and the diagnosis in one process, 22 s of real time."""
    from aeropend_core.testing.device_emulator import DeviceEmulator
    env = local_ros_environment(domain_id=private_domain_id())
    with DeviceEmulator(seed=5) as emulator:
        result = run_cli(['run', '--port', str(emulator.port), '--duration', '22', '--record', str(tmp_path),
                          '--window', '12', '--hop', '4'], env, timeout=150)
        emitted = [state for _, state in emulator.emitted]
    output = result.stdout + result.stderr
    assert result.returncode == 0, output
    assert 'rig on' in output and ' s: held-out fit ' in output and 'Diagnosis of' in output, output
    assert len(emitted) > 20 * 490
    from aeropend_core.io.bag import read_samples
    folder = next(p for p in tmp_path.iterdir() if p.is_dir())
    samples = read_samples(folder)
    assert samples['sequence'].size > 19 * 490, output
    assert np.mean(np.diff(samples['sequence']) == 1) > 0.99
    assert np.max(samples['duty']) > 0.1, 'the excitation reached the rig'


@pytest.mark.timeout(120)
@pytest.mark.parametrize('started_with', ['SIG_DFL', 'SIG_IGN'])
def test_run_interrupted_finalises_the_bag(tmp_path, started_with):
    """Ctrl-C (SIGINT) during `aeropend run`: duty back to 0, bag finalised and complete, exit status 130 -- also
    when the run was started with SIGINT ignored (a background job of a non-interactive shell inherits SIG_IGN;
    such a run used to ignore the signal and run to its end)."""
    import signal
    env = local_ros_environment(domain_id=private_domain_id())
    disposition = getattr(signal, started_with)
    run = subprocess.Popen(AEROPEND + ['run', '--duration', '120', '--realtime-factor', '3', '--record',
                                       str(tmp_path), '--no-diagnose', '--window', '10', '--hop', '5'],
                           env=env, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                           preexec_fn=lambda: signal.signal(signal.SIGINT, disposition))
    lines = []
    try:
        for line in run.stdout:              # wait for the first identified window, then interrupt
            lines.append(line)
            if ' s: held-out fit ' in line:
                run.send_signal(signal.SIGINT)
                break
        rest, _ = run.communicate(timeout=60)
    finally:
        if run.poll() is None:
            run.kill()
    output = ''.join(lines) + rest
    assert run.returncode == 130, output
    assert 'interrupted; finalising' in output and 'recorded:' in output and 'Traceback' not in output, output
    from aeropend_core.io.bag import read_samples
    folder = next(p for p in tmp_path.iterdir() if p.is_dir())
    assert (folder / 'metadata.yaml').exists()
    samples = read_samples(folder, on_incomplete='raise')
    assert samples['sequence'].size > 10 * 490 and np.all(np.diff(samples['sequence']) == 1)
    # cut short: every later diagnosis of this bag says so (a finding of the reader, as the data-quality gate's)
    from aeropend_core.io.recording import schedule_findings
    assert [f.code for f in schedule_findings(folder)] == ['schedule_incomplete']
    # The last duty command recorded is 0: the excitation was stopped before the graph went away.
    import struct
    from aeropend_core.io.bag import read_messages
    commands = [struct.unpack_from('<d', m.data, 4)[0] for m in read_messages(folder, ['/aeropend/duty_cmd'])]
    assert commands and max(commands) > 0.0 and commands[-1] == 0.0, commands[-5:]

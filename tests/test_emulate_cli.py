"""`aeropend emulate`: the fake rig from the shell, driven by README's calibration step 1, stopped by Ctrl-C."""
from __future__ import annotations

import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
AEROPEND = [sys.executable, '-c', 'import sys; from aeropend_core.cli import main; sys.exit(main())']

pytestmark = pytest.mark.timeout(120)


def value_of(output: str, key: str) -> float:
    line = next(line for line in output.splitlines() if line.startswith(f'{key}:'))
    return float(line.split(':', 1)[1].split('#')[0])


def test_emulate_serves_the_calibration_and_stops_on_ctrl_c(tmp_path):
    link = tmp_path / 'ttyRIG'
    emulate = subprocess.Popen(AEROPEND + ['emulate', '--link', str(link), '--angle-zero', '530', '--current-offset',
                                          '6', '--clock-error', '0.5', '--status-period', '0.5'],
                               cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(emulate.stdout), daemon=True)
    reader.start()
    try:
        deadline = time.monotonic() + 60
        while not lines and time.monotonic() < deadline:
            time.sleep(0.05)
        assert lines and lines[0].strip() == str(link), (lines, emulate.poll())
        assert any('auto-reset on' in line for line in lines[:8])
        # README "Calibration", step 1, against the fake rig.
        config = tmp_path / 'serial_bridge_node.yaml'
        config.write_text((ROOT / 'config' / 'serial_bridge_node.yaml').read_text())
        result = subprocess.run(AEROPEND + ['calibrate', 'zero', '--port', str(link), '--seconds', '1', '--write',
                                            str(config)], cwd=ROOT, capture_output=True, text=True, timeout=60)
        assert result.returncode == 0, result.stderr
        assert value_of(result.stdout, 'angle_zero') == pytest.approx(530.0, abs=0.5)
        assert value_of(result.stdout, 'current_offset') == pytest.approx(6.0, abs=0.5)
        assert 'angle_zero: 529' in config.read_text() or 'angle_zero: 530' in config.read_text()
        time.sleep(0.6)
        assert any('1 port opens' in line and '0 bytes swallowed' in line for line in lines), lines[-3:]
    finally:
        emulate.send_signal(signal.SIGINT)
        emulate.wait(timeout=30)
    reader.join(timeout=5)                         # the reader thread owns stdout until its end
    err = emulate.stderr.read()
    assert emulate.returncode == 130, err
    assert 'Traceback' not in err
    assert [line for line in lines if line.strip()][-1].startswith('# stopped after'), lines[-3:]
    assert not link.exists()                       # the port's name is removed


@pytest.mark.parametrize(('arguments', 'message'), [
    (['--clock-error', '9'], '--clock-error must be in [-5, 5] %'),
    (['--adc-noise', '-1'], '--adc-noise must be in'),
    (['--angle-zero', '2000'], '--angle-zero must be in [0, 1023]'),
    (['--link', '/nonexistent-folder/tty'], 'folder /nonexistent-folder does not exist'),
    (['--effect', 'warp_drive=1'], "unknown effect 'warp_drive'"),
])
def test_emulate_refuses_bad_options_in_one_line(arguments, message):
    result = subprocess.run(AEROPEND + ['emulate', *arguments, '--duration', '1'], cwd=ROOT, capture_output=True,
                            text=True, timeout=60)
    assert result.returncode == 2, result.stderr
    assert message in result.stderr and len(result.stderr.strip().splitlines()) == 1, result.stderr

"""`aeropend emulate`: the fake rig from the shell, driven by README's calibration step 1, stopped by Ctrl-C."""
from __future__ import annotations

import subprocess

import pytest

from tests.bridge_helpers import AEROPEND, ROOT, EmulateProcess, poll

pytestmark = pytest.mark.timeout(120)


def value_of(output: str, key: str) -> float:
    line = next(line for line in output.splitlines() if line.startswith(f'{key}:'))
    return float(line.split(':', 1)[1].split('#')[0])


@pytest.mark.slow
def test_emulate_serves_the_calibration_and_stops_on_ctrl_c(tmp_path):
    link = tmp_path / 'ttyRIG'
    with EmulateProcess(['--link', str(link), '--angle-zero', '530', '--current-offset', '6', '--clock-error', '0.5',
                         '--status-period', '0.5']) as emulate:
        lines = emulate.lines
        assert lines[0].strip() == str(link), lines
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
        assert poll(lambda: any('1 port opens' in line and '0 bytes swallowed' in line for line in lines), 30.0), \
            lines[-3:]
    assert emulate.returncode == 130, emulate.stderr
    assert 'Traceback' not in emulate.stderr
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

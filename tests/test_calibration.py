"""Rig calibration: the pure fits on synthetic data with known truth, and `aeropend calibrate` end to end against
the pty device emulator (its simulator's parameters are the truth; ADC quantisation is the only noise)."""
from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from aeropend_core.rig import calibration as C
from aeropend_core.rig import protocol as P
from aeropend_core.cli import main as aeropend
from aeropend_core.testing.device_emulator import DeviceEmulator
from aeropend_core.errors import InsufficientDataError
from aeropend_core.model.parameters import DEFAULT_PARAMETERS
from tests.bridge_helpers import ROOT, poll


def test_zero_and_scale_fits():
    rng = np.random.default_rng(1)
    angle = np.round(530.3 + rng.normal(0, 0.4, 1000))
    current = np.round(6.2 + rng.normal(0, 0.6, 1000))
    zero = C.zero_offsets(angle, current)
    assert zero.angle_zero == pytest.approx(530.3, abs=0.1)
    assert zero.current_offset == pytest.approx(6.2, abs=0.1)
    with pytest.raises(InsufficientDataError, match='moving'):
        C.zero_offsets(angle + 20 * np.sin(np.arange(1000) / 50), current)
    scale = C.angle_scale_from_reference(np.full(500, 530.3 - 256), 530.3, math.pi / 2)
    assert scale == pytest.approx(-2 * math.pi / 1024)       # sensor counting the other way
    with pytest.raises(InsufficientDataError, match='moved only'):
        C.angle_scale_from_reference(np.full(500, 532.0), 530.3, math.pi / 2)


def test_locked_rotor_and_back_emf_fits():
    rng = np.random.default_rng(2)
    current = np.array([0.25, 0.5, 0.75, 1.0, 1.2])
    voltage = 1.08 * current + 0.06 + rng.normal(0, 0.002, current.size)
    fit = C.locked_rotor_resistance(voltage, current)
    assert fit.value == pytest.approx(1.08, abs=3 * fit.sigma + 1e-3) and fit.intercept == pytest.approx(0.06, abs=0.01)
    with pytest.raises(InsufficientDataError, match='at least 3'):
        C.locked_rotor_resistance(voltage[:2], current[:2])
    with pytest.raises(InsufficientDataError, match='changed by only'):
        C.locked_rotor_resistance([0.1, 0.11, 0.12], [0.1, 0.11, 0.12])
    speed = np.array([800.0, 1200.0, 1500.0])
    current = np.array([0.4, 0.6, 0.8])
    voltage = 6.6e-4 * speed + 1.08 * current
    assert C.back_emf_constant(voltage, current, speed, 1.08).value == pytest.approx(6.6e-4, rel=1e-6)
    assert C.back_emf_constant(voltage[:1], current[:1], speed[:1], 1.08).value == pytest.approx(6.6e-4)
    with pytest.raises(InsufficientDataError, match='positive'):
        C.back_emf_constant(voltage, current, -speed, 1.08)


def run_cli(capsys, *argv) -> tuple[int, str, str]:
    status = aeropend(['calibrate', *argv])
    captured = capsys.readouterr()
    return status, captured.out, captured.err


def value_of(output: str, key: str) -> float:
    line = next(line for line in output.splitlines() if line.startswith(f'{key}:'))
    return float(line.split(':', 1)[1].split('#')[0])


def test_calibrate_cli_against_the_emulator(capsys, tmp_path):
    # The emulated sensor reads 530 counts hanging down and 6 counts at zero current: calibration must find them.
    truth = P.Calibration(angle_zero=530.0, current_offset=6.0)
    config = tmp_path / 'serial_bridge_node.yaml'
    config.write_text((ROOT / 'config' / 'serial_bridge_node.yaml').read_text())
    with DeviceEmulator(calibration=truth, seed=3) as emulator:
        status, out, err = run_cli(capsys, 'zero', '--port', emulator.port, '--seconds', '1', '--write', str(config))
        assert status == 0, err
        assert value_of(out, 'angle_zero') == pytest.approx(530.0, abs=0.5)
        assert value_of(out, 'current_offset') == pytest.approx(6.0, abs=0.5)
        written = yaml.safe_load(config.read_text())['/**/serial_bridge_node']['ros__parameters']
        assert written['angle_zero'] == pytest.approx(530.0, abs=0.5)
        assert written['max_duty'] == 0.7 and '# [s] the firmware stops' in config.read_text()   # rest untouched

        # Locked rotor: Va = Ra Ia in steady state; the simulator's Ra is the truth.
        emulator.locked_rotor = True
        status, out, err = run_cli(capsys, 'locked-rotor', '--port', emulator.port, '--config', str(config),
                                   '--duties', '0.05,0.1,0.15,0.2', '--dwell', '0.6')
        assert status == 0, err
        assert value_of(out, 'armature_resistance') == pytest.approx(DEFAULT_PARAMETERS.armature_resistance,
                                                                     rel=0.02)
        emulator.locked_rotor = False

        # Back-EMF at duty 0.5 with the motor speed a tachometer would read (the model's steady state).
        steady = DEFAULT_PARAMETERS.steady_state(DEFAULT_PARAMETERS.voltage_from_duty(0.5))
        rpm = steady['motor_speed'] * 60 / (2 * math.pi)
        status, out, err = run_cli(capsys, 'back-emf', '--port', emulator.port, '--config', str(config),
                                   '--duty', '0.5', '--motor-speed-rpm', f'{rpm:.0f}',
                                   '--resistance', str(DEFAULT_PARAMETERS.armature_resistance), '--dwell', '2.5')
        assert status == 0, err
        assert value_of(out, 'back_emf_constant') == pytest.approx(DEFAULT_PARAMETERS.back_emf_constant, rel=0.03)
        assert 'mA of PWM ripple subtracted' in out
        # The emulated rig reads the current at the pulse centre (its measurement chain): uncorrected, that
        # reading is tens of mA above the period average and Kw comes out several per cent low.
        status, out, err = run_cli(capsys, 'back-emf', '--port', emulator.port, '--config', str(config),
                                   '--duty', '0.5', '--motor-speed-rpm', f'{rpm:.0f}', '--no-ripple-correction',
                                   '--resistance', str(DEFAULT_PARAMETERS.armature_resistance), '--dwell', '2.5')
        assert status == 0, err
        assert value_of(out, 'back_emf_constant') < 0.96 * DEFAULT_PARAMETERS.back_emf_constant
        # The motor is left at duty 0 (the emulator reads its input every ~20 ms).
        assert poll(lambda: emulator.commands[-1][1] == P.CommandFrame(P.SET_DUTY, 0), 20.0)


def test_calibrate_cli_user_errors(capsys, tmp_path):
    status, _, err = run_cli(capsys, 'zero', '--port', str(tmp_path / 'nothing'))
    assert status == 2 and 'cannot open' in err
    status, _, err = run_cli(capsys, 'back-emf', '--port', str(tmp_path / 'nothing'), '--duty', '0.5')
    assert status == 2 and '--motor-speed-rpm' in err

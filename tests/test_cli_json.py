"""``--json [FILE]`` on every verb, one meaning: the verb's result as JSON to FILE, or to standard output with ``-``
or no FILE (standard output then carries the JSON only). A user mistake exits 2 with one line on standard error
before any work, and no JSON is written (the file is not created, standard output stays empty)."""
from __future__ import annotations

import json
import time

import numpy as np
import pytest

from aeropend_core.cli import main as cli_main
from tests.bridge_helpers import EmulateProcess



def run(capsys, *arguments):
    status = cli_main(list(arguments))
    out, err = capsys.readouterr()
    return status, out, err


def test_simulate_json_to_stdout_and_file(tmp_path, capsys):
    csv = tmp_path / 'run.csv'
    status, out, err = run(capsys, 'simulate', '-o', str(csv), '--duration', '2', '--seed', '3', '--psnr', '40',
                           '--effect', 'coulomb_friction=4', '--json')
    assert status == 0, err
    summary = json.loads(out)                                       # the JSON only on standard output
    assert summary['samples'] == 980 and summary['duration'] == 2.0 and summary['sample_rate'] == 490.0
    assert summary['effects'] == {'coulomb_friction': {'friction_acceleration': 4.0}}
    assert summary['psnr_db'] == 40.0 and summary['seed'] == 3 and summary['output'] == str(csv)
    written = np.genfromtxt(csv, delimiter=',', names=True)
    assert list(written.dtype.names) == summary['columns'] and written.size == summary['samples']
    # to a file: the CSV still written, the JSON in the file, nothing on standard output
    status, out, err = run(capsys, 'simulate', '-o', str(csv), '--duration', '1', '--json', str(tmp_path / 's.json'))
    assert status == 0 and out == ''
    assert json.loads((tmp_path / 's.json').read_text())['samples'] == 490


@pytest.mark.parametrize(('arguments', 'message'), [
    (['simulate', '--duration', '1', '--json'], '--json - and the CSV cannot both go to standard output'),
    (['simulate', '-o', '{d}/run.csv', '--json', '{d}'], '--json {d} is a folder'),
    (['simulate', '-o', '{d}/run.csv', '--json', '{d}/missing/s.json'], 'missing'),
    (['bag-recover', '{d}/nothing', '--json', '{d}/r.json'], 'nothing'),
    (['effects', '--json', '{d}'], '--json {d} is a folder'),
    (['identify', '{d}/none.csv', '--json', '{d}/i.json'], 'none.csv'),
    (['diagnose', '{d}/none.csv', '--json', '{d}'], '--json {d} is a folder'),
    (['calibrate', 'zero', '--port', '{d}/tty', '--json', '{d}'], '--json {d} is a folder'),
    (['emulate', '--json', '{d}'], '--json {d} is a folder'),
    (['run', '--no-diagnose', '--json'], '--report and --json describe the diagnosis'),
    (['run', '--json', '{d}'], '--json {d} is a folder'),
    (['monitor', '--json', '{d}/missing/m.jsonl'], 'missing'),
])
def test_user_mistakes_exit_2_and_write_no_json(tmp_path, capsys, arguments, message):
    arguments = [a.replace('{d}', str(tmp_path)) for a in arguments]
    before = set(tmp_path.iterdir())
    status, out, err = run(capsys, *arguments)
    assert status == 2, (out, err)
    assert out == '' and err.count('\n') == 1 and message.replace('{d}', str(tmp_path)) in err, err
    assert set(tmp_path.iterdir()) == before                      # no JSON file (nor anything else) left


def test_effects_json_bare_flag_and_file(tmp_path, capsys):
    status, out, _ = run(capsys, 'effects', '--json')
    catalog = json.loads(out)
    assert status == 0 and catalog['coulomb_friction']['parameters']['friction_acceleration']['unit']
    status, out, _ = run(capsys, 'effects', '--json', str(tmp_path / 'c.json'))
    assert status == 0 and json.loads((tmp_path / 'c.json').read_text()) == catalog
    assert out.strip() == f'json: {tmp_path / "c.json"}'


def test_identify_json_file_keeps_the_text_and_writes_strict_json(tmp_path, capsys):
    csv = tmp_path / 'run.csv'
    assert run(capsys, 'simulate', '-o', str(csv), '--duration', '12', '--seed', '5', '--psnr', '50')[0] == 0
    status, out, err = run(capsys, 'identify', str(csv), '--json', str(tmp_path / 'i.json'))
    assert status == 0, err
    assert 'gravity_stiffness' in out                              # the text as without --json
    text = (tmp_path / 'i.json').read_text()
    result = json.loads(text)                                     # strict JSON: json.loads refuses NaN only if told
    assert 'NaN' not in text and result['estimator'] == 'weak_sindy'
    assert result['parameters']['gravity_stiffness'] == pytest.approx(131.75, rel=0.1)
    status, out, _ = run(capsys, 'identify', str(csv), '--json', '-')
    assert status == 0 and json.loads(out)['parameters'] == result['parameters']


def test_bag_recover_json(tmp_path, capsys):
    from tests.test_bag import write_bag
    bag = tmp_path / 'bag'
    write_bag(bag, 300).close()
    status, out, err = run(capsys, 'bag-recover', str(bag), '--json')
    assert status == 0, err
    report = json.loads(out)                                       # the text went to standard error
    assert report['bag'] == str(bag) and report['message_count'] == 300 + 7 and report['repaired'] == []
    assert len(report['intact']) == 1 and 'messages in' in err


def test_calibrate_json_against_the_emulator(capsys):
    from aeropend_core.rig import protocol as P
    from aeropend_core.testing.device_emulator import DeviceEmulator
    with DeviceEmulator(calibration=P.Calibration(angle_zero=530.0, current_offset=6.0), seed=3) as emulator:
        status, out, err = run(capsys, 'calibrate', 'zero', '--port', emulator.port, '--seconds', '1', '--json')
    assert status == 0, err
    result = json.loads(out)                                       # the '#' and key lines went to standard error
    assert result['step'] == 'zero' and result['values']['angle_zero']['unit'] == 'count'
    assert result['values']['angle_zero']['value'] == pytest.approx(530.0, abs=0.5)
    assert result['values']['current_offset']['where'] == 'config/serial_bridge_node.yaml'
    assert result['details']['samples'] > 100 and 'angle_zero:' in err


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_emulate_json_line_names_the_port_then_ctrl_c(tmp_path):
    link = tmp_path / 'ttyRIG'
    with EmulateProcess(['--link', str(link), '--json', '-', '--status-period', '0.5']) as emulate:
        info = json.loads(emulate.lines[0])
        assert info['link'] == str(link) and info['port'] == str(link) and link.resolve().exists()   # the pty
        assert info['auto_reset'] is True and info['chain']['angle_filter'] is True
        time.sleep(1.2)                                            # status lines come meanwhile: on stderr
    assert emulate.returncode == 130 and 'Traceback' not in emulate.stderr
    assert len([line for line in emulate.lines if line.strip()]) == 1, emulate.lines   # standard output: JSON only
    assert '# stopped after' in emulate.stderr

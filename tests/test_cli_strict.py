"""The command line never guesses: a mistake gets the verb's own usage and one error line with a suggestion, exit 2.

Issue #24 item 2. Every case runs in-process through :func:`aeropend_core.cli.main` (the parser is the same as the
installed `aeropend`), so the table is fast; the verbs that need ROS (`run`, `monitor`) are only parsed here.
"""
from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from aeropend_core.cli import main

ROOT = Path(__file__).resolve().parents[1]


def call(capsys, *argv: str) -> tuple[int, str, str]:
    """(exit status, stdout, stderr) of `aeropend ARGV` in-process."""
    try:
        status = main(list(argv))
    except SystemExit as stop:
        status = stop.code if isinstance(stop.code, int) else 1
    out, err = capsys.readouterr()
    return status, out, err


#: (arguments, the suggestion the error line must carry); every one was misread or answered with the top-level usage
#: before (prefix matching, `--effect` for `--effects-module`, typos with `usage: aeropend [-h] VERB ...`)
MISTAKES = [
    pytest.param(['diagnose', 'x.csv', '--effect', 'coulomb_friction=3'], '--add', id='diagnose-effect-is-add'),
    pytest.param(['diagnose', 'x.csv', '--ad', 'coulomb_friction'], '--add', id='diagnose-prefix-ad'),
    pytest.param(['diagnose', 'x.csv', '--effects', 'x.py'], '--add', id='diagnose-prefix-effects'),
    pytest.param(['diagnose', 'x.csv', '--reprot', 'r.html'], '--report', id='diagnose-typo-report'),
    pytest.param(['diagnose', 'x.csv', '--no-drfit'], '--no-drift', id='diagnose-typo-no-drift'),
    pytest.param(['diagnose', 'x.csv', '--quite'], '--quiet', id='diagnose-typo-quiet'),
    pytest.param(['identify', 'x.csv', '--mdl', 'pendulum'], '--model', id='identify-typo-model'),
    pytest.param(['identify', 'x.csv', '--calib', 'c.yaml'], '--calibration', id='identify-prefix-calibration'),
    pytest.param(['simulate', '--dur', '5'], '--duration', id='simulate-prefix-duration'),
    pytest.param(['simulate', '--sed', '3'], '--seed', id='simulate-typo-seed'),
    pytest.param(['simulate', '--quantize'], '--quantise', id='simulate-spelling-quantise'),
    pytest.param(['effects', '--jsn'], '--json', id='effects-typo-json'),
    pytest.param(['bag-recover', 'b', '--keep-orig'], '--keep-original', id='bag-recover-prefix'),
    pytest.param(['run', '--durration', '30'], '--duration', id='run-typo-duration'),
    pytest.param(['run', '--real', '4'], '--realtime-factor', id='run-prefix-realtime'),
    pytest.param(['run', '--model-efect', 'x'], '--add', id='run-typo-model-effect'),
    pytest.param(['monitor', '--onse'], '--once', id='monitor-typo-once'),
    pytest.param(['monitor', '--plot-fil', 'p.png'], '--plot-file', id='monitor-prefix-plot-file'),
    pytest.param(['emulate', '--efect', 'x=1'], '--effect', id='emulate-typo-effect'),
]


@pytest.mark.parametrize('argv, suggestion', MISTAKES)
def test_an_option_mistake_gets_the_verbs_own_usage_and_one_line_with_a_suggestion(capsys, argv, suggestion):
    status, out, err = call(capsys, *argv)
    verb = argv[0]
    assert status == 2, err
    assert out == ''
    lines = err.strip().splitlines()
    assert lines[0].startswith(f'usage: aeropend {verb} '), err            # the verb's usage, not `aeropend VERB ...`
    errors = [line for line in lines if ': error:' in line]
    assert len(errors) == 1, err
    assert errors[0].startswith(f'aeropend {verb}: error: unrecognized option '), err
    assert f'(did you mean {suggestion}?)' in errors[0], err
    assert 'Traceback' not in err


EFFECT_MISTAKES = [
    pytest.param(['diagnose', '{csv}', '--add', 'colomb_friction'], 'coulomb_friction', id='diagnose-add'),
    pytest.param(['diagnose', '{csv}', '--only', 'cable_torq'], 'cable_torque', id='diagnose-only'),
    pytest.param(['identify', '{csv}', '--add', 'angle_ofset'], 'angle_offset', id='identify-add'),
    pytest.param(['simulate', '--duration', '1', '--effect', 'thrustlag=0.1'], 'thrust_lag', id='simulate-effect'),
    pytest.param(['run', '--add', 'deadzone'], 'dead_zone', id='run-add'),
    pytest.param(['run', '--effect', 'quadratic_dag=0.1'], 'quadratic_drag', id='run-hidden-effect'),
]


@pytest.mark.parametrize('argv, suggestion', EFFECT_MISTAKES)
def test_an_unknown_effect_name_gets_did_you_mean(capsys, tmp_path, argv, suggestion):
    csv = tmp_path / 'r.csv'
    csv.write_text('t,duty,armature_voltage,armature_current,angle\n0,0,0,0,0\n')
    argv = [a.format(csv=csv) for a in argv]
    status, out, err = call(capsys, *argv)
    assert status == 2, err
    assert f'(did you mean {suggestion}?)' in err, err
    assert len(err.strip().splitlines()) == 1, err                # one line, no usage dump for a bad value
    assert err.startswith(f'aeropend {argv[0]}: error: unknown effect'), err


def test_an_unknown_verb_gets_the_closest_verb(capsys):
    status, _, err = call(capsys, 'diagnoze', 'x.csv')
    assert status == 2
    assert "unknown verb 'diagnoze' (did you mean diagnose?)" in err, err


def test_version(capsys):
    status, out, _ = call(capsys, '--version')
    assert status == 0
    assert re.fullmatch(r'aeropend \d+\.\d+\.\d+\n', out), out


@pytest.mark.parametrize('verb', ['simulate', 'identify', 'diagnose', 'effects', 'bag-recover', 'calibrate',
                                  'emulate', 'import', 'run', 'monitor'])
def test_every_help_shows_its_defaults_and_its_own_usage(capsys, verb):
    status, out, _ = call(capsys, verb, '--help')
    assert status == 0
    assert out.startswith(f'usage: aeropend {verb}')
    from aeropend_core.cli import verb_parser
    parser = verb_parser(verb)
    options = out[out.index('\noptions:'):]
    entries = re.split(r'\n  (?=-)', options)              # one entry per option: its flags, then its help
    for action in parser._actions:
        if action.default in (None, False, [], '==SUPPRESS==') or not action.option_strings or \
                action.help == '==SUPPRESS==':
            continue
        entry = next(e for e in entries if re.match(r'(-\S+ ?\S*, )*' + re.escape(action.option_strings[-1]), e))
        assert 'default' in entry.lower(), f'{verb} {action.option_strings[-1]}: no default in its help:\n{entry}'


def test_identify_takes_add_like_diagnose_and_the_old_effect_still_works_with_a_deprecation_line(capsys, tmp_path):
    csv = tmp_path / 'r.csv'
    csv.write_text('t,duty,armature_voltage,armature_current,angle\n0,0,0,0,0\n')
    status, _, err = call(capsys, 'identify', str(csv), '--add', 'warp')
    assert status == 2 and "unknown effect 'warp' in --add" in err, err
    status, _, err = call(capsys, 'identify', str(csv), '--effect', 'warp')
    assert status == 2
    assert 'aeropend identify: warning: --effect is deprecated; write --add' in err, err
    assert "unknown effect 'warp' in --add" in err, err
    _, out, _ = call(capsys, 'identify', '--help')
    assert '--add EFFECT' in out and '--effect' not in out


def test_run_accepts_fix_as_its_help_promises(capsys):
    _, out, _ = call(capsys, 'run', '--help')
    assert '--fix angle_filter=' in out                           # the promise (in --calibration's help)
    # accepted by the parser and checked before any node starts: a fix that is also added is refused in one line
    status, _, err = call(capsys, 'run', '--fix', 'angle_filter=0.0141', '--add', 'angle_filter')
    assert status == 2
    assert err.startswith('aeropend run: error: angle_filter given with both --add and --fix'), err
    status, _, err = call(capsys, 'run', '--fix', 'angle_filtr=0.01')
    assert status == 2 and '(did you mean angle_filter?)' in err, err


def test_psnr_zero_means_no_noise_in_simulate_as_in_run(tmp_path, capsys):
    clean, zero = tmp_path / 'clean.csv', tmp_path / 'zero.csv'
    assert call(capsys, 'simulate', '-o', str(clean), '--duration', '2', '--quiet')[0] == 0
    status, _, err = call(capsys, 'simulate', '-o', str(zero), '--duration', '2', '--psnr', '0')
    assert status == 0, err
    assert clean.read_bytes() == zero.read_bytes()
    _, out, _ = call(capsys, 'run', '--help')
    assert '0 = none' in out or '0 = no noise' in out


def test_quiet_long_verbs_write_nothing_to_stderr_and_progress_never_goes_to_stdout(tmp_path, capsys):
    csv = tmp_path / 'r.csv'
    status, out, err = call(capsys, 'simulate', '-o', str(csv), '--duration', '1')
    assert status == 0 and out == '' and err.startswith('wrote ')        # progress: standard error
    status, out, err = call(capsys, 'simulate', '-o', str(csv), '--duration', '1', '--quiet')
    assert status == 0 and out == '' and err == ''
    for verb in ('simulate', 'identify', 'diagnose', 'import', 'run'):
        _, out, _ = call(capsys, verb, '--help')
        assert '--quiet' in out, verb


def test_the_same_positional_name_for_the_record(capsys):
    for verb in ('identify', 'diagnose'):
        _, out, _ = call(capsys, verb, '--help')
        assert re.search(r'usage: aeropend %s .*RECORDING' % verb, re.sub(r'\s+', ' ', out)), out


def test_monitor_help_jq_example_reads_the_lines_monitor_writes(capsys):
    """The jq filter of `monitor --help` applied (by jq's own rules) to a line `monitor --json` writes."""
    _, out, _ = call(capsys, 'monitor', '--help')
    example = next(line for line in out.splitlines() if '| jq' in line)
    path = re.search(r"\.window\.parameters\.(\w+)", example)
    assert path, example
    from aeropend_ros.cli.monitor import _json_line

    class Status:
        level = 0
        message = 'ok'
    line = _json_line(Status, {}, {'stamp_ns': 1, 'parameters': {path.group(1): (3.0, 0.1)}, 'coefficients': {},
                                   'fit': {}}, lambda name: 'rad/s^2/V^2')
    line = json.loads(json.dumps(line))
    assert line['window']['parameters'][path.group(1)]['value'] == 3.0
    import shutil
    if shutil.which('jq'):
        query = example.split('| jq', 1)[1].strip().split(' ', 1)[1].strip().strip("'")
        result = subprocess.run(['jq', '-c', query], input=json.dumps(line) + '\n' + json.dumps({'time': 0}) + '\n',
                                capture_output=True, text=True, check=True)
        assert json.loads(result.stdout.strip())['value'] == 3.0


def test_the_installed_command_answers_a_mistake_with_the_verbs_usage(tmp_path):
    """The same through a real process (what a user sees): exit 2, the verb's usage, one error line."""
    result = subprocess.run([sys.executable, '-c', 'import sys; from aeropend_core.cli import main; sys.exit(main())',
                             'diagnose', 'x.csv', '--effect', 'coulomb_friction=3'], capture_output=True, text=True,
                            cwd=ROOT, timeout=120, check=False)
    assert result.returncode == 2
    assert result.stderr.startswith('usage: aeropend diagnose')
    assert result.stderr.strip().splitlines()[-1] == ('aeropend diagnose: error: unrecognized option --effect (did '
                                                      'you mean --add?); see aeropend diagnose --help')


def test_monitor_json_gives_numbers_as_numbers():
    """The diagnostic values ROS carries as text reach the JSON as numbers where they are numbers (issue #42 item 6:
    they were all strings), and text stays text."""
    from aeropend_ros.cli.monitor import _json_line

    class Status:
        level = 0
        message = 'ok'
    line = json.loads(json.dumps(_json_line(Status, {'window_seconds': '25.0', 'samples': '12250',
                                                     'estimators': 'damping:output_error', 'odd': 'nan'},
                                            None, lambda name: '')))
    assert line['values']['window_seconds'] == 25.0 and line['values']['samples'] == 12250
    assert line['values']['estimators'] == 'damping:output_error' and line['values']['odd'] == 'nan'


def test_verb_entry_points_equal_importlib_metadata():
    """The fast scan of ``entry_points.txt`` finds exactly what ``importlib.metadata`` selects (issue #41: the
    metadata of every installed distribution is no longer built for `aeropend --help`)."""
    from importlib.metadata import entry_points

    from aeropend_core.cli import VERB_GROUP, _verb_entry_points
    expected = sorted((point.name, point.value) for point in entry_points(group=VERB_GROUP))
    assert sorted((point.name, point.value) for point in _verb_entry_points()) == expected
    assert {'run', 'monitor'} <= {name for name, _ in expected}


def test_help_reads_no_distribution_metadata(capsys, monkeypatch):
    """`aeropend --help` must not scan every distribution (``packages_distributions`` cost ~1 s with ROS wheels):
    the version is read only when ``--version`` asks for it."""
    import importlib.metadata

    def refuse():
        raise AssertionError('packages_distributions() called for --help')
    monkeypatch.setattr(importlib.metadata, 'packages_distributions', refuse)
    status, out, _ = call(capsys, '--help')
    assert status == 0 and out.startswith('usage: aeropend')


def test_a_core_verb_is_parsed_without_scanning_the_entry_points(monkeypatch):
    """A core verb's command line reads no distribution's metadata (a plugin cannot replace a core verb): the
    scan and importlib.metadata cost ~0.05-0.1 s of every `aeropend control check`."""
    import aeropend_core.cli as cli

    def scanned():
        raise AssertionError('the entry points were scanned for a core verb')
    monkeypatch.setattr(cli, '_verb_entry_points', scanned)
    parser, args = cli.parse_arguments(['effects'])
    assert args.verb == 'effects' and parser.prog == 'aeropend effects'
    with pytest.raises(AssertionError, match='scanned'):
        cli.parse_arguments(['no-such-verb'])

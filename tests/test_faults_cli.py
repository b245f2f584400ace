"""Fault injection on the `aeropend` command: bad files, bad data and bad arguments to every verb.

Each case runs the real console script in a fresh process and requires: a non-zero exit status, no Python
traceback (nor the top-level "internal error" line that stands for one), and a message naming the problem. The
bad files are made from one simulated record (CSV, and MCAP bags written by aeropend_core.io.bag with CDR from the
independent `rosbags` serialiser), built once per module. ROS verbs (run, monitor, calibrate) are only given
arguments that must be refused before any node starts, plus one full-disk run where the refusal matters.

Cases already covered elsewhere are not repeated: test_diagnose (missing file, unknown --add), test_identify
(missing file, missing column), test_bag (garbage .mcap to bag-recover), test_run_cli (missing serial port,
unknown effect, --model-effect with a value).
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from aeropend_core.io.bag_writer import BagWriter
from aeropend_core.io.mcap_format import msg_file_loader, offered_qos, ros2msg_definition
from aeropend_core.sim.excitation import lhc_schedule
from aeropend_core.model.parameters import SAMPLE_TIME
from aeropend_core.sim.noise import MeasurementNoise
from aeropend_core.sim.simulate import simulate
from aeropend_ros._ros_env import local_ros_environment
from tests.ros_helpers import ROOT, private_domain_id
from tests.test_bag import mcap_stream_count, small_disk

pytestmark = pytest.mark.timeout(300)

SCRIPT = Path(sys.executable).with_name('aeropend')
#: the installed console script when there is one (the real entry point), else the same main() through -c
AEROPEND = [str(SCRIPT)] if SCRIPT.exists() else [
    sys.executable, '-c', 'import sys; from aeropend_core.cli import main; sys.exit(main())']
COLUMNS = ('t', 'duty', 'armature_voltage', 'armature_current', 'angle')
CHANNELS = ('angle', 'armature_voltage', 'armature_current', 'duty', 'sequence')
DURATION = 24.0                  # s: long enough for the diagnosis (>= 20 s)
T0_NS = 1_763_700_000_000_000_000


def aeropend(arguments: list[str], env: dict | None = None, timeout: float = 120.0, preexec_fn=None):
    return subprocess.run(AEROPEND + arguments, cwd=ROOT, capture_output=True, text=True, timeout=timeout,
                          env=env, preexec_fn=preexec_fn, check=False)


def assert_refused(result, keywords: tuple[str, ...], status: int = 2) -> None:
    """Exit `status`, every keyword in standard error (case-insensitive), no traceback, no internal error."""
    err = result.stderr
    assert result.returncode == status, f'exit {result.returncode}, expected {status}\n{err}{result.stdout}'
    assert 'Traceback' not in err and 'internal error' not in err, err
    for keyword in keywords:
        assert keyword.lower() in err.lower(), f'{keyword!r} not in the message:\n{err}'
    assert len([line for line in err.splitlines() if 'error' in line]) <= 2, err     # one clear line, not a dump


# ------------------------------------------------------------------------------------------------------------------
# The files: one simulated record and what goes wrong with recordings
# ------------------------------------------------------------------------------------------------------------------
def write_csv(path: Path, time: np.ndarray, signals: dict[str, np.ndarray]) -> None:
    table = np.column_stack([time] + [signals[c] for c in COLUMNS[1:]])
    np.savetxt(path, table, delimiter=',', header=','.join(COLUMNS), comments='', fmt='%.9g')


def write_bag(folder: Path, time: np.ndarray, signals: dict[str, np.ndarray], topic: str = '/aeropend/samples',
              chunk_size: int = 64 * 1024) -> None:
    """JointState samples serialised by rosbags (not by our code) into a bag written by BagWriter."""
    from rosbags.typesys import Stores, get_typestore
    store = get_typestore(Stores.ROS2_JAZZY)
    joint_state = store.types['sensor_msgs/msg/JointState']
    header, stamp_type = store.types['std_msgs/msg/Header'], store.types['builtin_interfaces/msg/Time']
    prefixes = [p for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p] + [sys.prefix]
    writer = BagWriter(folder, chunk_size=chunk_size)
    type_name = 'sensor_msgs/msg/JointState'
    writer.add_topic(topic, type_name, ros2msg_definition(type_name, msg_file_loader(prefixes)),
                     [offered_qos('best_effort', depth=5)])
    empty = np.array([], dtype=float)
    for k, t in enumerate(time):
        stamp = T0_NS + round(float(t) * 1e9)
        values = [signals[c][k] if c != 'sequence' else float(signals['sequence'][k]) for c in CHANNELS]
        message = joint_state(header=header(stamp=stamp_type(sec=stamp // 10**9, nanosec=stamp % 10**9),
                                            frame_id='aeropend'),
                              name=list(CHANNELS), position=np.array(values, dtype=float), velocity=empty,
                              effort=empty)
        writer.write(topic, store.serialize_cdr(message, type_name), stamp)
    writer.finish()


@pytest.fixture(scope='module')
def files(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp('faults')
    schedule = lhc_schedule(DURATION, duty_range=(0.0, 0.7), seed=3, duty_cap=0.7)
    trajectory = simulate(schedule.duty(SAMPLE_TIME, DURATION), noise=MeasurementNoise(50.0, True), seed=3)
    columns = trajectory.columns(with_truth=False)
    time = np.asarray(columns['t'])
    signals = {c: np.asarray(columns[c], dtype=float) for c in COLUMNS[1:]}
    signals['sequence'] = np.arange(len(time), dtype=float)

    def variant(**changes):
        out = {k: v.copy() for k, v in signals.items()}
        for key, (index, value) in changes.items():
            out[key][index] = value
        return out

    write_csv(d / 'base.csv', time, signals)
    write_csv(d / 'nan.csv', time, variant(angle=(1000, np.nan)))
    write_csv(d / 'inf.csv', time, variant(armature_current=(700, np.inf)))
    stamps = time.copy()
    stamps[[1000, 1001]] = stamps[[1001, 1000]]
    write_csv(d / 'backwards.csv', stamps, signals)
    stamps = time.copy()
    stamps[2000] = stamps[1999]
    write_csv(d / 'clash.csv', stamps, signals)                       # same stamp, different values
    stamps = time.copy()
    stamps[300] = np.nan
    write_csv(d / 'nan_time.csv', stamps, signals)
    write_csv(d / 'rate_zero.csv', np.zeros_like(time), signals)      # a logger whose clock did not run
    repeat = np.sort(np.r_[np.arange(len(time)), np.arange(2000, 2100)])
    write_csv(d / 'duplicated.csv', time[repeat], {k: v[repeat] for k, v in signals.items()})
    flat = simulate(np.full(len(time), 0.4), noise=MeasurementNoise(50.0, True), seed=3).columns(with_truth=False)
    write_csv(d / 'unexcited.csv', np.asarray(flat['t']), {c: np.asarray(flat[c]) for c in COLUMNS[1:]})
    keep = np.ones(len(time), dtype=bool)
    keep[3000:3010] = False                                           # ten samples lost on the way
    write_csv(d / 'gap.csv', time[keep], {k: v[keep] for k, v in signals.items()})
    short = int(5.0 / SAMPLE_TIME)
    write_csv(d / 'short.csv', time[:short], {k: v[:short] for k, v in signals.items()})
    (d / 'empty.csv').write_text('')
    (d / 'header_only.csv').write_text(','.join(COLUMNS) + '\n')
    (d / 'text.csv').write_text(','.join(COLUMNS) + '\n0,0.1,abc,0,0\n')
    (d / 'ragged.csv').write_text(','.join(COLUMNS) + '\n0,0.1,1.0,0,0\n0.002,0.1,1.0\n')
    (d / 'binary.csv').write_bytes(b'\xff\xfe\x00\x81' * 64)
    (d / 'notes.txt').write_text('not a recording\n')
    (d / 'garbage.mcap').write_bytes(b'not an mcap file' * 64)
    (d / 'no_mcap').mkdir()

    write_bag(d / 'bag', time, signals)
    write_bag(d / 'wrong_topic', time, signals, topic='/other/samples')
    write_bag(d / 'nan_bag', time, variant(angle=(600, np.nan)))
    stamps = time.copy()
    stamps[1000] -= 0.01
    write_bag(d / 'backwards_bag', stamps, signals)
    write_bag(d / 'duplicated_bag', time[repeat], {k: v[repeat] for k, v in signals.items()})
    data = (d / 'bag' / 'bag_0.mcap').read_bytes()
    (d / 'cut_tiny.mcap').write_bytes(data[:200])                    # cut before its first chunk
    (d / 'cut_half.mcap').write_bytes(data[:len(data) // 2])          # cut in the middle of a chunk
    return d


# ------------------------------------------------------------------------------------------------------------------
# Bad recordings: identify and diagnose
# ------------------------------------------------------------------------------------------------------------------
#: (file, keywords of the message). Both verbs must refuse each file.
BAD_RECORDINGS = [
    pytest.param('no_bag', ('no such file',), id='missing-bag-folder'),
    pytest.param('notes.txt', ('unknown recording type', '.csv'), id='unknown-file-type'),
    pytest.param('empty.csv', ('empty',), id='empty-csv'),
    pytest.param('header_only.csv', ('no samples',), id='csv-header-only'),
    pytest.param('text.csv', ('non-numeric',), id='csv-non-numeric'),
    pytest.param('ragged.csv', ('row 2', 'fields'), id='csv-ragged-rows'),
    pytest.param('binary.csv', ('not a text CSV',), id='csv-binary'),
    pytest.param('nan_time.csv', ('time stamp', 'not finite', 'sample 300'), id='nan-time-stamp'),
    pytest.param('backwards.csv', ('backwards', 'sample 1001'), id='non-monotonic-stamps'),
    pytest.param('clash.csv', ('same time stamp', 'samples 1999 and 2000'), id='same-stamp-different-values'),
    pytest.param('rate_zero.csv', ('same time stamp', 'samples 0 and 1'), id='sample-rate-zero'),
    pytest.param('unexcited.csv', ('excit',), id='unexcited-constant-duty'),
    pytest.param('garbage.mcap', ('not an MCAP file',), id='not-an-mcap'),
    pytest.param('no_mcap', ('no .mcap file',), id='folder-without-mcap'),
    pytest.param('cut_tiny.mcap', ('cut short', 'bag-recover'), id='mcap-truncated-before-first-chunk'),
    pytest.param('wrong_topic', ('no /aeropend/samples', '/other/samples'), id='bag-wrong-topics'),
]


@pytest.mark.parametrize('verb', ['identify', 'diagnose'])
def test_one_stamp_out_of_order_in_a_bag_is_skipped_and_said_not_a_refusal(files, verb):
    """Issue #43: one damaged stamp in a bag (sample 1000 stamped 10 ms early) no longer refuses the whole bag:
    the sample is skipped, the span and count said, and everything else analysed (a CSV's backwards stamps are
    still refused: there the stamps are the user's own column, not the recorder's)."""
    result = aeropend([verb, str(files / 'backwards_bag')])
    assert result.returncode == 0, result.stderr
    assert 'Traceback' not in result.stderr and 'internal error' not in result.stderr
    assert 'out of order' in result.stderr and '1 sample(s)' in result.stderr and 'skipped' in result.stderr


@pytest.mark.parametrize('verb', ['identify', 'diagnose'])
@pytest.mark.parametrize('name, keywords', BAD_RECORDINGS)
def test_bad_recording_is_refused_clearly(files, verb, name, keywords):
    assert_refused(aeropend([verb, str(files / name)]), keywords)


@pytest.mark.slow
def test_lost_samples_split_the_record_at_the_gap_for_identify_and_diagnose(files):
    fitted = aeropend(['identify', str(files / 'gap.csv'), '--json'])
    assert fitted.returncode == 0 and 'gap' in fitted.stderr, fitted.stderr
    assert json.loads(fitted.stdout)['gaps'] == {'count': 1, 'pieces': 2}
    result = aeropend(['diagnose', str(files / 'gap.csv'), '--json', '--quiet'])
    assert result.returncode == 0 and 'Traceback' not in result.stderr, result.stderr
    report = json.loads(result.stdout)
    gaps = report['gaps']
    assert (gaps['count'], gaps['lost_samples']) == (1, 10)
    assert gaps['longest_seconds'] == pytest.approx(10 * SAMPLE_TIME, rel=1e-3)
    assert any('gap' in note for note in report['notes'])


def test_too_short_for_the_diagnosis(files):
    assert_refused(aeropend(['diagnose', str(files / 'short.csv')]), ('at least 20 s',))


def identify_json(files: Path, name: str, *extra: str) -> tuple[dict, str]:
    result = aeropend(['identify', str(files / name), '--json', '--stop', '8', *extra])
    assert result.returncode == 0 and 'Traceback' not in result.stderr, result.stderr
    return json.loads(result.stdout), result.stderr


@pytest.mark.slow
@pytest.mark.parametrize('name, clean_name, dropped', [('duplicated.csv', 'base.csv', 100),
                                                       ('duplicated_bag', 'bag', 100)])
def test_duplicated_samples_are_dropped_with_a_warning_and_change_nothing(files, name, clean_name, dropped):
    """Exact repeats (same stamp, same values) are dropped, said in one warning line; the numbers are those of the
    clean record (not silently different)."""
    clean, _ = identify_json(files, clean_name)
    repeated, err = identify_json(files, name)
    assert 'warning: ' in err and f'dropped {dropped} duplicated sample(s)' in err, err
    assert repeated['samples'] == clean['samples']
    assert repeated['coefficients'] == clean['coefficients']
    assert clean['warnings'] == [] and [w['code'] for w in repeated['warnings']] == ['duplicate_sample']


@pytest.mark.slow
@pytest.mark.parametrize('name, keywords', [('nan.csv', ('angle', 'sample 1000', 'interpolation')),
                                            ('inf.csv', ('armature_current', 'sample 700', 'interpolation')),
                                            ('nan_bag', ('angle', 'sample 600', 'interpolation'))])
def test_isolated_non_finite_sample_is_interpolated_and_said(files, name, keywords):
    """One NaN/inf sample: interpolated by the data-quality gate, one warning line naming it, and the same
    "warnings" entry in --json (never a number without its warning)."""
    out, err = identify_json(files, name)
    lines = [line for line in err.splitlines() if 'warning: ' in line]
    assert len(lines) == 1 and all(k.lower() in lines[0].lower() for k in keywords), err
    assert [w['code'] for w in out['warnings']] == ['non_finite'] and out['warnings'][0]['severity'] == 'repaired'


@pytest.mark.slow
def test_truncated_bag_is_read_to_its_last_chunk_with_a_warning(files):
    """A bag cut mid-chunk (killed recorder): the complete chunks are used and a one-line warning says so and how
    to repair it."""
    expected = mcap_stream_count(files / 'cut_half.mcap')            # the mcap library's stream reader
    assert 0 < expected < mcap_stream_count(files / 'bag' / 'bag_0.mcap')
    result = aeropend(['identify', str(files / 'cut_half.mcap'), '--json'])
    assert result.returncode == 0 and 'Traceback' not in result.stderr, result.stderr
    warning = [line for line in result.stderr.splitlines() if 'warning' in line]
    assert len(warning) == 1 and 'incomplete' in warning[0] and 'bag-recover' in warning[0], result.stderr
    assert json.loads(result.stdout)['samples'] == expected           # no fewer, no more


# ------------------------------------------------------------------------------------------------------------------
# Bad arguments: every verb
# ------------------------------------------------------------------------------------------------------------------
#: (arguments with {d} for the data folder, keywords of the message, exit status)
BAD_ARGUMENTS = [
    # simulate
    pytest.param(['simulate', '-o', '{d}/o.csv', '--duration', '-1'], ('--duration',), 2,
                 id='simulate-negative-duration'),
    pytest.param(['simulate', '-o', '{d}/o.csv', '--duration', 'inf'], ('--duration', '3600'), 2,
                 id='simulate-infinite-duration'),
    pytest.param(['simulate', '-o', '{d}/o.csv', '--duration', '0.001'], ('two samples',), 2,
                 id='simulate-duration-below-one-sample'),
    pytest.param(['simulate', '-o', '{d}/o.csv', '--duration', '1', '--psnr', '-5'], ('--psnr',), 2,
                 id='simulate-negative-psnr'),
    pytest.param(['simulate', '-o', '{d}/o.csv', '--duration', '1', '--psnr', '1e6'], ('--psnr', '200'), 2,
                 id='simulate-psnr-overflow'),
    pytest.param(['simulate', '-o', '{d}/o.csv', '--duration', '1', '--seed', '-1'], ('--seed',), 2,
                 id='simulate-negative-seed'),
    pytest.param(['simulate', '-o', '{d}/o.csv', '--seed', 'abc'], ('--seed', 'invalid int'), 2,
                 id='simulate-seed-not-a-number'),
    pytest.param(['simulate', '-o', '{d}/o.csv', '--max-duty', '0'], ('--max-duty',), 2, id='simulate-zero-duty'),
    pytest.param(['simulate', '-o', '{d}/o.csv', '--effect', 'warp_drive=1'], ('unknown effect', 'coulomb_friction'),
                 2, id='simulate-unknown-effect'),
    pytest.param(['simulate', '-o', '{d}/o.csv', '--effect', 'coulomb_friction=abc'], ('NAME=VALUE',), 2,
                 id='simulate-effect-value-not-a-number'),
    pytest.param(['simulate', '-o', '{d}/o.csv', '--effect', 'coulomb_friction'], ('NAME=VALUE',), 2,
                 id='simulate-effect-without-value'),
    pytest.param(['simulate', '-o', '{d}/o.csv', '--effect', 'coulomb_friction=-4'], ('outside',), 2,
                 id='simulate-effect-out-of-range'),
    pytest.param(['simulate', '-o', '{d}/o.csv', '--effect', 'coulomb_friction.nope=4'], ('no parameter',), 2,
                 id='simulate-effect-unknown-parameter'),
    pytest.param(['simulate', '-o', '{d}/no_such_folder/o.csv', '--duration', '1'], ('does not exist',), 2,
                 id='simulate-output-folder-missing'),
    pytest.param(['simulate', '-o', '{d}', '--duration', '1'], ('is a folder',), 2, id='simulate-output-is-a-folder'),
    # identify
    pytest.param(['identify', '{d}/base.csv', '--start', '10', '--stop', '5'], ('before --stop',), 2,
                 id='identify-start-after-stop'),
    pytest.param(['identify', '{d}/base.csv', '--start', '100'], ('no samples', 'spans'), 2,
                 id='identify-window-outside-record'),
    pytest.param(['identify', '{d}/base.csv', '--start', 'nan'], ('--start', 'finite'), 2, id='identify-start-nan'),
    pytest.param(['identify', '{d}/base.csv', '--add', 'warp'], ('unknown effect',), 2,
                 id='identify-unknown-effect'),
    pytest.param(['identify', '{d}/base.csv', '--add', 'cable_torque=3'], ('name only',), 2,
                 id='identify-effect-with-value'),
    pytest.param(['identify', '{d}/base.csv', '--model', 'full-state'], ('motor_speed',), 2,
                 id='identify-full-state-without-truth'),
    # diagnose
    pytest.param(['diagnose', '{d}/base.csv', '--add', 'coulomb_friction=4'], ('name only',), 2,
                 id='diagnose-effect-with-value'),
    pytest.param(['diagnose', '{d}/base.csv', '--only', 'warp'], ('unknown effect', '--only'), 2,
                 id='diagnose-unknown-candidate'),
    pytest.param(['diagnose', '{d}/base.csv', '--report', '{d}/no_such_folder/r.html'], ('does not exist',), 2,
                 id='diagnose-report-folder-missing'),
    pytest.param(['diagnose', '{d}/base.csv', '--effects-module', '{d}/none.py'], ('does not exist',), 2,
                 id='diagnose-effects-module-missing'),
    # effects
    pytest.param(['effects', '--bogus'], ('unrecognized option --bogus',), 2, id='effects-unknown-option'),
    # bag-recover
    pytest.param(['bag-recover', '{d}/no_bag'], ('does not exist',), 2, id='bag-recover-missing'),
    pytest.param(['bag-recover', '{d}/base.csv'], ('not an MCAP file',), 2, id='bag-recover-csv'),
    pytest.param(['bag-recover', '{d}/no_mcap'], ('no .mcap file',), 2, id='bag-recover-folder-without-mcap'),
    # run (refused before any node starts)
    pytest.param(['run', '--duration', '-1'], ('--duration',), 2, id='run-negative-duration'),
    pytest.param(['run', '--duration', 'inf'], ('--duration',), 2, id='run-infinite-duration'),
    pytest.param(['run', '--psnr', '-3'], ('--psnr',), 2, id='run-negative-psnr'),
    pytest.param(['run', '--seed', '-1'], ('--seed',), 2, id='run-negative-seed'),
    pytest.param(['run', '--window', '1'], ('--window',), 2, id='run-window-too-short'),
    pytest.param(['run', '--realtime-factor', '0'], ('--realtime-factor',), 2, id='run-zero-speed'),
    pytest.param(['run', '--duty-cap', '1.5'], ('--duty-cap',), 2, id='run-duty-cap-above-one'),
    pytest.param(['run', '--record', '/proc/aeropend_bags'], ('--record', 'cannot create'), 2,
                 id='run-record-folder-impossible'),
    # monitor
    pytest.param(['monitor', '--once', '--timeout', '0'], ('--timeout',), 2, id='monitor-zero-timeout'),
    pytest.param(['monitor', '--duration', '-5'], ('--duration',), 2, id='monitor-negative-duration'),
    pytest.param(['monitor', '--drift-sigma', '0'], ('--drift-sigma',), 2, id='monitor-zero-drift-threshold'),
    # calibrate (refused before the port is opened)
    pytest.param(['calibrate', 'locked-rotor', '--port', '/dev/nonexistent', '--duties', '0.1,0.2,0.9'],
                 ('duty 0.9', '--max-duty'), 2, id='calibrate-duty-above-cap'),
    pytest.param(['calibrate', 'locked-rotor', '--port', '/dev/nonexistent', '--duties', '0.1'],
                 ('at least three',), 2, id='calibrate-too-few-duties'),
    pytest.param(['calibrate', 'locked-rotor', '--port', '/dev/nonexistent', '--duties', '0.1,abc'],
                 ('--duties', 'comma-separated'), 2, id='calibrate-duties-not-numbers'),
    pytest.param(['calibrate', 'zero', '--port', '/dev/nonexistent', '--seconds', '-1'], ('--seconds',), 2,
                 id='calibrate-negative-seconds'),
    pytest.param(['calibrate', 'zero', '--port', '/dev/nonexistent', '--max-duty', '2'], ('--max-duty',), 2,
                 id='calibrate-max-duty-above-one'),
    pytest.param(['calibrate', 'back-emf', '--port', '/dev/nonexistent', '--duty', '0.5', '--motor-speed-rpm',
                  '8000'], ('--resistance',), 2, id='calibrate-back-emf-without-resistance'),
    pytest.param(['calibrate', 'zero', '--port', '/dev/nonexistent'], ('cannot open', 'plugged in'), 2,
                 id='calibrate-missing-port'),
]


@pytest.fixture(scope='module')
def ros_env() -> dict:
    return local_ros_environment(domain_id=private_domain_id())


@pytest.mark.parametrize('arguments, keywords, status', BAD_ARGUMENTS)
def test_bad_arguments_are_refused_clearly(files, ros_env, arguments, keywords, status):
    arguments = [a.replace('{d}', str(files)) for a in arguments]
    assert_refused(aeropend(arguments, env=ros_env), keywords, status)
    assert not (files / 'o.csv').exists(), 'a refused simulate left an output file'


# ------------------------------------------------------------------------------------------------------------------
# Full disk: simulate, and the whole graph with its recorder
# ------------------------------------------------------------------------------------------------------------------
def test_simulate_on_a_full_disk_fails_clearly_and_leaves_no_partial_file(tmp_path):
    with small_disk(tmp_path, 64 * 1024) as (disk, preexec, how):
        print(f'full disk simulated with {how}')
        result = aeropend(['simulate', '-o', str(disk / 'run.csv'), '--duration', '20'], preexec_fn=preexec)
        assert_refused(result, ('cannot write', 'run.csv', 'nothing was written'), status=1)
        assert 'No space left on device' in result.stderr or 'File too large' in result.stderr, (how, result.stderr)
        assert not any(disk.iterdir()), f'left behind: {list(disk.iterdir())}'


@pytest.mark.timeout(180)
def test_run_stops_with_a_clear_error_when_its_recording_disk_fills(tmp_path, ros_env):
    """`aeropend run` records to a disk that fills up: the run stops early with the recorder's error (exit 1),
    and the bag keeps its complete chunks (bag-recover finalises it)."""
    with small_disk(tmp_path, 192 * 1024) as (disk, preexec, how):
        print(f'full disk simulated with {how}')
        result = aeropend(['run', '--duration', '60', '--realtime-factor', '4', '--record', str(disk),
                           '--no-diagnose'], env=ros_env, timeout=150, preexec_fn=preexec)
        assert_refused(result, ('recording failed', 'bag-recover'), status=1)
        assert 'No space left on device' in result.stderr or 'File too large' in result.stderr, (how, result.stderr)
        bag = next(p for p in disk.iterdir() if p.is_dir())
        copy = tmp_path / 'bag'
        shutil.copytree(bag, copy)
    repaired = aeropend(['bag-recover', str(copy)])          # into copy_recovered, the original left as it was
    assert repaired.returncode == 0 and 'recovered into' in repaired.stdout, repaired.stderr
    from aeropend_core.io.bag import read_samples
    sequence = read_samples(copy.with_name(copy.name + '_recovered'), on_incomplete='raise')['sequence']
    assert sequence.size > 0 and np.all(np.diff(sequence) == 1)


# ------------------------------------------------------------------------------------------------------------------
# The top level: bugs are named as bugs, the traceback is one variable away
# ------------------------------------------------------------------------------------------------------------------
def test_internal_error_is_one_line_that_says_bug_and_debug_shows_the_traceback(monkeypatch, capsys):
    from aeropend_core import cli
    from aeropend_core.cli import effects

    def broken(args):
        return 1 / 0
    monkeypatch.setattr(effects, 'main', broken)
    monkeypatch.delenv('AEROPEND_DEBUG', raising=False)
    assert cli.main(['effects']) == 1
    err = capsys.readouterr().err
    assert 'internal error: ZeroDivisionError' in err and 'AEROPEND_DEBUG=1' in err and 'report' in err
    assert 'Traceback' not in err and 'test_faults_cli.py' in err          # where it happened, in one line
    monkeypatch.setenv('AEROPEND_DEBUG', '1')
    with pytest.raises(ZeroDivisionError):
        cli.main(['effects'])


def test_os_error_nobody_handled_names_the_file_and_the_reason(monkeypatch, capsys):
    from aeropend_core import cli
    from aeropend_core.cli import effects

    def refused(args):
        raise PermissionError(13, 'Permission denied', 'catalog.json')
    monkeypatch.setattr(effects, 'main', refused)
    monkeypatch.delenv('AEROPEND_DEBUG', raising=False)
    assert cli.main(['effects']) == 1
    err = capsys.readouterr().err
    assert err.strip() == 'aeropend effects: error: catalog.json: Permission denied (errno 13)'


# ------------------------------------------------------------------------------------------------------------------
# Corrupted recordings (issue 12): the data-quality gate, for identify and diagnose
# ------------------------------------------------------------------------------------------------------------------
from aeropend_core.testing.faults import FAULTS  # noqa: E402

#: A word of the refusal message for each refused finding code.
REFUSAL_WORDS = {'stuck_sensor': 'stuck', 'sample_rate_mismatch': '490 Hz', 'time_precision': 'rounded',
                 'duplicate_column': 'both named'}
FAULT_BY_NAME = {fault.name: fault for fault in FAULTS}
#: Pairs tried on the command line (all pairs are tried on the gate itself in test_quality).
CLI_PAIRS = [('angle_wrapped_0_2pi', 'angle_in_degrees'), ('outlier_100rad', 'time_in_milliseconds'),
             ('glitch_2pi', 'nan_sample'), ('current_outlier', 'current_in_milliamps'),
             ('outlier_1e308', 'outlier_1e300'), ('angle_stuck_6s', 'angle_in_degrees'),
             ('lost_1s', 'time_rounded_1e5s')]


@pytest.fixture(scope='module')
def faulted(tmp_path_factory) -> Path:
    """One clean 60 s record (known truth) and every fault of aeropend_core.testing.faults applied to it."""
    from aeropend_core.io.recording import write_csv as write_full
    d = tmp_path_factory.mktemp('faulted')
    schedule = lhc_schedule(60.0, duty_range=(0.0, 0.7), seed=1, duty_cap=0.7)
    trajectory = simulate(schedule.duty(SAMPLE_TIME, 60.0), noise=MeasurementNoise(40.0, True), seed=1)
    clean = {k: np.asarray(v, dtype=float) for k, v in trajectory.columns(with_truth=False).items()}
    write_full(str(d / 'clean.csv'), clean)
    for fault in FAULTS:
        write_full(str(d / f'{fault.name}.csv'), fault.apply(clean))
    for first, second in CLI_PAIRS:
        a, b = sorted((FAULT_BY_NAME[first], FAULT_BY_NAME[second]), key=lambda f: f.stage)
        write_full(str(d / f'{first}+{second}.csv'), b.apply(a.apply(clean)))
    text = (d / 'clean.csv').read_text()
    (d / 'excel.csv').write_bytes(b'\xef\xbb\xbf' + text.encode())
    header, _, body = text.partition('\n')
    rows = [row + ',' + row.split(',')[4] for row in body.splitlines()]
    (d / 'twice.csv').write_text(header + ',angle\n' + '\n'.join(rows) + '\n')
    return d


@pytest.fixture(scope='module')
def clean_identify(faulted) -> dict:
    result = aeropend(['identify', str(faulted / 'clean.csv'), '--json'])
    assert result.returncode == 0, result.stderr
    out = json.loads(result.stdout)
    assert out['warnings'] == [] and 'warning' not in result.stderr
    assert out['parameters']['gravity_stiffness'] == pytest.approx(131.75, rel=0.03)     # the truth
    return out


def expected_codes(name: str) -> tuple[set[str], set[str]]:
    """(codes that must be reported, codes of which one must refuse) for a fault or a pair 'a+b'."""
    faults = [FAULT_BY_NAME[part] for part in name.split('+')]
    codes = {f.code for f in faults}
    refused = {f.code for f in faults if f.severity == 'refused'}
    if name == 'lost_1s+time_rounded_1e5s':
        refused = {'time_precision'}             # no uniform grid fits rounded stamps with a gap in them
    if 'angle_wrapped' in codes:
        codes.discard('angle_jump')
    return codes, refused


CLI_CASES = [fault.name for fault in FAULTS] + [f'{a}+{b}' for a, b in CLI_PAIRS]


@pytest.mark.slow
@pytest.mark.parametrize('name', CLI_CASES)
def test_identify_refuses_or_says_every_repair(faulted, clean_identify, name):
    """Refused (exit 2, one line naming the problem) or exit 0 with a warning line per finding, the same list in
    --json "warnings", and the clean record's numbers (lost samples: said first, then fitted on the pieces between
    the gaps, JSON "gaps")."""
    codes, refused = expected_codes(name)
    result = aeropend(['identify', str(faulted / f'{name}.csv'), '--json'])
    if refused:
        assert_refused(result, (REFUSAL_WORDS[next(iter(refused))], 't = '))
        return
    assert result.returncode == 0 and 'Traceback' not in result.stderr, result.stderr
    out = json.loads(result.stdout)
    if 'lost_samples' in codes:     # said first, then the weak form is fitted on the pieces between the gaps
        assert 'lost_samples' in result.stderr.splitlines()[0], result.stderr
        assert out['gaps']['count'] >= 1, out['gaps']
    assert codes <= {w['code'] for w in out['warnings']}, out['warnings']
    warned = [line for line in result.stderr.splitlines() if 'aeropend identify: warning: ' in line]
    assert len(warned) == len(out['warnings']) and all(f"[{w['code']}, " in line
                                                       for w, line in zip(out['warnings'], warned))
    for key in ('gravity_stiffness', 'damping', 'thrust_gain'):
        reference = clean_identify['parameters'][key]
        tolerance = max(0.01 * abs(reference), clean_identify['parameter_standard_errors'][key])
        assert abs(out['parameters'][key] - reference) <= tolerance, (key, out['parameters'][key], reference)


@pytest.mark.slow
def test_identify_text_output_has_a_data_quality_section(faulted):
    result = aeropend(['identify', str(faulted / 'glitch_2pi.csv')])
    assert result.returncode == 0, result.stderr
    assert 'Data quality: 1 finding(s)' in result.stdout and 'angle_jump' in result.stdout
    assert result.stdout.index('Data quality') < result.stdout.index('gravity_stiffness')


@pytest.mark.parametrize('name', [fault.name for fault in FAULTS])
def test_diagnose_gate_runs_before_the_fit(faulted, name, monkeypatch, capsys):
    """The gate's findings are printed before the (slow) diagnosis starts, and a refusal costs no fit: the fit is
    replaced by a probe that records what it was given and stops the command."""
    import aeropend_core.diagnosis.diagnose as diagnosis_module
    from aeropend_core.cli import main
    given = []

    def probe(recording, **kwargs):
        given.append(recording)
        raise KeyboardInterrupt

    monkeypatch.setattr(diagnosis_module, 'diagnose', probe)
    status = main(['diagnose', str(faulted / f'{name}.csv'), '--quiet'])
    err = capsys.readouterr().err
    codes, refused = expected_codes(name)
    if refused:
        assert status == 2 and not given and 'error: ' in err and REFUSAL_WORDS[next(iter(refused))] in err, err
        return
    assert status == 130 and len(given) == 1, err
    assert codes <= {f.code for f in given[0].findings}
    warned = [line for line in err.splitlines() if line.startswith('aeropend diagnose: warning: ')]
    assert len(warned) == len(given[0].findings) and err.index('warning') < err.index('interrupted'), err


def diagnose_json(path: Path, *extra: str) -> dict:
    result = aeropend(['diagnose', str(path), '--json', '--quiet', '--only', 'cable_torque', '--only',
                       'coulomb_friction', *extra], timeout=300)
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout)


@pytest.fixture(scope='module')
def clean_diagnosis(faulted) -> dict:
    return diagnose_json(faulted / 'clean.csv')


@pytest.mark.slow
@pytest.mark.parametrize('name', ['glitch_2pi', 'angle_in_degrees', 'outlier_1e308'])
def test_diagnose_repaired_record_gives_the_clean_verdict(faulted, clean_diagnosis, name):
    """Full diagnoses on representative faults: the 2 pi encoder glitch once named cable_torque as the missing
    effect; repaired and said, the verdict and the fit are the clean record's."""
    clean = clean_diagnosis
    report = faulted / f'{name}.html'
    out = diagnose_json(faulted / f'{name}.csv', '--report', str(report))
    page = report.read_text()
    assert 'Data quality: 1 finding(s)' in page and FAULT_BY_NAME[name].code in page     # the report says it too
    assert page.index('id="data-quality"') < page.index('id="verdict"')
    assert clean['warnings'] == [] and FAULT_BY_NAME[name].code in {w['code'] for w in out['warnings']}
    assert out['verdict'] == clean['verdict'] == 'nothing_missing' and out['missing_effect'] is None
    assert out['fit_percent'] == pytest.approx(clean['fit_percent'], abs=0.5)


@pytest.mark.slow
def test_excel_byte_order_mark_loads_with_a_note(faulted, clean_identify):
    result = aeropend(['identify', str(faulted / 'excel.csv'), '--json'])
    assert result.returncode == 0, result.stderr
    out = json.loads(result.stdout)
    assert [w['code'] for w in out['warnings']] == ['byte_order_mark'] and 'byte-order mark' in result.stderr
    assert out['parameters'] == clean_identify['parameters']


@pytest.mark.parametrize('verb', ['identify', 'diagnose'])
def test_duplicated_angle_column_is_refused(faulted, verb):
    assert_refused(aeropend([verb, str(faulted / 'twice.csv')]), ('columns 5 and 6', "both named 'angle'"))


@pytest.mark.slow
def test_lost_samples_are_the_first_thing_said(files):
    """A gap: the gate's warning (how many, where) comes before anything else, then the fit's own answer."""
    result = aeropend(['diagnose', str(files / 'gap.csv'), '--quiet'])
    first = result.stderr.splitlines()[0]
    assert 'warning' in first and '10 sample(s) lost' in first and 'lost_samples' in first, result.stderr

"""Issue 42 items 1, 4, 5 and 6: another rig's CSV recognised and its profile guessed, a current's wrong scale said
beside Ra, a cut-short run said in every later diagnosis and a run's diagnosis saved beside its bag, and the paper
cuts (a report named .png, `run --quantise`, `effects NAME`, `diagnose bags/`, help anchors, bare `aeropend`,
the JSON's schema key). In-process through the real command line; nothing here fits a model except the one test
marked slow.
"""
from __future__ import annotations

import json
import math
import os
import re
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from aeropend_core.errors import AeropendError
from tests.test_cli_strict import call

ROOT = Path(__file__).resolve().parents[1]


# ------------------------------------------------------------------------------------------------------------------
# Item 1: another rig's CSV
# ------------------------------------------------------------------------------------------------------------------
FOREIGN = {
    'semicolon': ('pc_time;pwm;A0;enc\n2026-03-14 15:09:26.535;100;300;45\n2026-03-14 15:09:26.580;100;310;47\n',
                  'separated by semicolons'),
    'datetime': ('pc_time,pwm,A0,enc\n2026-03-14 15:09:26.535,100,300,45\n2026-03-14 15:09:26.580,100,310,47\n',
                 'non-numeric value'),
    'names': ('millis,duty_pct,theta_deg\n1234,40.0,2.5\n1279,40.0,2.7\n', 'no column named t or angle'),
}


@pytest.mark.parametrize('kind', sorted(FOREIGN))
def test_another_rigs_csv_is_recognised_and_the_error_names_import_with_a_guessed_profile(tmp_path, capsys, kind):
    text, problem = FOREIGN[kind]
    log = tmp_path / 'rig_log.csv'
    log.write_text(text)
    status, out, err = call(capsys, 'diagnose', str(log), '--quiet')
    assert status == 2 and 'Traceback' not in err
    line = err.strip().splitlines()[-1]
    assert "not in aeropend's own CSV format" in line and problem in line, line
    assert f'aeropend import {log} --guess-profile' in line and '--profile' in line, line
    assert 'could not convert' not in line.split('(')[0]           # the parser's words are not the lead
    # the command the error names writes a profile that reads the log
    target = re.search(r'--guess-profile (\S+)`', line).group(1)
    status, _, err = call(capsys, 'import', str(log), '--guess-profile', target)
    assert status == 0, err
    profile = yaml.safe_load(Path(target).read_text())
    assert 'angle' in profile['columns']


def test_a_text_log_not_named_csv_is_recognised_too(tmp_path, capsys):
    log = tmp_path / 'rig_log.txt'
    log.write_text(FOREIGN['datetime'][0])
    status, _, err = call(capsys, 'identify', str(log))
    assert status == 2 and "another rig's log" in err and '--guess-profile' in err, err


def test_guessed_profile_of_a_generated_log_matches_the_generators_own(tmp_path):
    """A ;-separated log with millis(), duty in %, angle in degrees: delimiter, clock and units guessed as written."""
    from aeropend_core.io.profile_guess import guess_profile
    from aeropend_core.testing.foreign_logs import ForeignLogSpec, generate
    log = generate(ForeignLogSpec(seed=3, duration=3.0, periods_per_line=10, stamps='device_ms', duty='percent',
                                  angle='degrees', current='none',
                                  column_names={'time': 'millis', 'current': 'i', 'angle': 'theta_deg',
                                                'duty': 'duty_pct'}))
    path = tmp_path / 'log.csv'
    path.write_text(log.text.replace(',', ';'))
    profile, guesses = guess_profile(path)
    assert profile['delimiter'] == ';'
    assert profile['clock'] == {'column': 'millis', 'kind': 'milliseconds', 'source': 'device'}
    assert profile['columns']['angle'] == {'column': 'theta_deg', 'unit': 'deg'}
    assert profile['columns']['duty'] == {'column': 'duty_pct', 'unit': 'percent'}
    assert len(guesses) >= 4


def test_a_typo_in_our_own_format_keeps_its_own_message(tmp_path, capsys):
    path = tmp_path / 'run.csv'
    path.write_text('t,duty,armature_voltage,armature_current,angle\n0,0.5,5,0.3,0.1\n0.002,0.5,5,oops,0.1\n')
    status, _, err = call(capsys, 'diagnose', str(path), '--quiet')
    assert status == 2 and 'non-numeric value' in err and 'another rig' not in err


def test_the_shipped_sample_logs_import_through_their_profiles(tmp_path, capsys):
    """samples/ holds the logs the README and docs/log-import.md use, each read by its profile."""
    for log, profile in (('rig_log.csv', 'config/profiles/arduino_logger.yaml'),
                         ('rig_log_semicolon.csv', 'samples/rig_log_semicolon.yaml')):
        out = tmp_path / f'{log}.imported.csv'
        status, _, err = call(capsys, 'import', str(ROOT / 'samples' / log), '--profile', str(ROOT / profile),
                              '-o', str(out), '--quiet')
        assert status == 0, err
        header = [line for line in out.read_text().splitlines() if not line.startswith('#')][0]
        assert header.startswith('t,duty,armature_voltage') and header.endswith('angle')


# ------------------------------------------------------------------------------------------------------------------
# Item 4: a current's scale and the armature resistance
# ------------------------------------------------------------------------------------------------------------------
def test_an_implausible_resistance_gets_a_doubt_naming_the_current_scale():
    from aeropend_core.identify.plausibility import current_scale_ratio, resistance_doubt
    from aeropend_core.model.parameters import DEFAULT_PARAMETERS as P
    # the observer's p1 = Kw Kt / (Jm Rm) of the stated motor, and Rm as a current 2.963 x too small makes it
    drive = P.back_emf_constant * P.torque_constant / (P.motor_inertia * P.armature_resistance)
    scaled = {'motor_drive_rate': drive, 'motor_resistance': 2.963 * P.armature_resistance}
    assert current_scale_ratio(scaled) == pytest.approx(2.963, rel=1e-9)
    text = resistance_doubt(3.18, 0.004, current_scale_ratio(scaled))
    assert text.startswith('DOUBT') and 'current' in text and 'observer agrees' in text
    assert resistance_doubt(1.10, 0.01, 1.0) == ''                      # the stated motor: no doubt
    assert resistance_doubt(1.30, 0.2, 1.0) == ''                       # within 1.5 x
    other_motor = resistance_doubt(2.5, 0.01, 1.02)
    assert 'may really differ' in other_motor                          # the observer says the scale is right


# ------------------------------------------------------------------------------------------------------------------
# Item 5: a run cut short
# ------------------------------------------------------------------------------------------------------------------
def test_a_bag_whose_run_was_cut_short_says_so_in_its_findings(tmp_path):
    from aeropend_core.io.recording import bag_findings
    bag = tmp_path / 'run1'
    bag.mkdir()
    info = {'rosbag2_bagfile_information': {'version': 9, 'custom_data': {
        'aeropend.schedule_complete': 'false', 'aeropend.schedule_seconds': '60.000000'}}}
    (bag / 'metadata.yaml').write_text(yaml.safe_dump(info))
    findings = bag_findings(bag, [])
    assert [f.code for f in findings] == ['schedule_incomplete']
    assert findings[0].severity == 'warning' and 'cut short' in findings[0].message and '60.0 s' in findings[0].message
    info['rosbag2_bagfile_information']['custom_data']['aeropend.schedule_complete'] = 'true'
    (bag / 'metadata.yaml').write_text(yaml.safe_dump(info))
    assert bag_findings(bag, []) == ()


def test_a_runs_diagnosis_is_saved_beside_its_bag(tmp_path, monkeypatch):
    """`aeropend run` calls this after its summary: the JSON (schema key) and the report next to the bag folder."""
    from aeropend_core.cli import _checks
    bag = tmp_path / 'aeropend_20261206_210000'
    bag.mkdir()
    written_reports = []

    def fake_report(diagnosis, path, source=''):
        Path(path).write_text('<html></html>')
        written_reports.append((path, source))
        return Path(path)

    import aeropend_core.present.report as report
    monkeypatch.setattr(report, 'write_report', fake_report)

    class Stub:               # a Diagnosis presents itself as --json prints it (Diagnosis.to_dict)
        def to_dict(self):
            return {'schema': 'aeropend.diagnosis/1', 'x': math.nan}
    paths = _checks.save_beside_bag(Stub(), bag)
    assert paths == [str(tmp_path / 'aeropend_20261206_210000.diagnosis.json'),
                     str(tmp_path / 'aeropend_20261206_210000.report.html')]
    assert json.loads(Path(paths[0]).read_text()) == {'schema': 'aeropend.diagnosis/1', 'x': None}
    assert written_reports == [(paths[1], str(bag))] and sorted(os.listdir(bag)) == []   # the bag is untouched


# ------------------------------------------------------------------------------------------------------------------
# Item 6: paper cuts
# ------------------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize('verb', ['diagnose', 'control'])
def test_a_report_named_png_is_refused_before_any_work(tmp_path, capsys, verb):
    argv = ['diagnose', str(tmp_path / 'none.csv')] if verb == 'diagnose' else ['control', 'check',
                                                                                 str(tmp_path / 'none')]
    status, _, err = call(capsys, *argv, '--report', str(tmp_path / 'out.png'))
    assert status == 2 and 'HTML page' in err and '.html' in err, err
    assert not (tmp_path / 'out.png').exists()


def test_run_quantise_says_the_run_already_quantises_not_did_you_mean_quiet(capsys):
    status, _, err = call(capsys, 'run', '--quantise')
    assert status == 2
    line = err.strip().splitlines()[-1]
    assert 'quantises' in line and 'aeropend simulate' in line and '--quiet' not in line, line


def test_effects_with_a_name_shows_that_effect_and_what_to_do_with_it(capsys):
    status, out, _ = call(capsys, 'effects', 'thrust_lag')
    assert status == 0
    assert out.startswith('thrust_lag') and 'coulomb_friction' not in out
    assert '--effect thrust_lag=' in out and '--add thrust_lag' in out
    status, _, err = call(capsys, 'effects', 'thrust_lga')
    assert status == 2 and 'thrust_lag' in err


def test_diagnose_of_a_folder_of_bags_names_the_newest(tmp_path, capsys):
    folder = tmp_path / 'bags'
    for index, name in enumerate(('aeropend_1', 'aeropend_2')):
        (folder / name).mkdir(parents=True)
        (folder / name / 'metadata.yaml').write_text('rosbag2_bagfile_information: {}\n')
        os.utime(folder / name, (time.time() - 100 + index, time.time() - 100 + index))
    status, _, err = call(capsys, 'diagnose', str(folder), '--quiet')
    assert status == 2
    line = err.strip().splitlines()[-1]
    assert 'folder of 2 records' in line and f'newest, {folder / "aeropend_2"}' in line, line
    (tmp_path / 'empty').mkdir()
    status, _, err = call(capsys, 'diagnose', str(tmp_path / 'empty'), '--quiet')
    assert status == 2 and 'holds no bag' in err


def test_bare_aeropend_prints_help_on_stdout_with_status_0(capsys):
    status, out, err = call(capsys)
    assert status == 0 and out.startswith('usage: aeropend') and 'diagnose' in out and err == ''


def _headings(path: Path) -> set[str]:
    from tests.test_docs import anchors
    return anchors(path)


def test_every_readme_or_docs_section_a_help_text_cites_exists():
    """The verbs' and nodes' help texts cite README/docs sections: each cited file, #anchor and quoted section
    exists (`run --help` pointed at a README section that had moved)."""
    sources = [*sorted((ROOT / 'aeropend_core' / 'cli').glob('*.py')), *sorted((ROOT / 'aeropend_ros').glob('*.py')),
               *sorted((ROOT / 'aeropend_ros' / 'cli').glob('*.py'))]
    cited = 0
    missing = []
    for source in sources:
        text = source.read_text(encoding='utf-8')
        for page, anchor, quoted in re.findall(r'(README|(?:docs|bench/results)/[a-z_-]+\.md)(?:#([a-z0-9-]+)|,? '
                                               r'"([^"]+)")?', text):
            path = ROOT / ('README.md' if page == 'README' else page)
            cited += 1
            if not path.is_file():
                missing.append(f'{source.name}: {page}')
                continue
            wanted = anchor or (quoted and re.sub(r'[^\w\- ]', '', quoted.lower()).replace(' ', '-'))
            if wanted and wanted not in _headings(path):
                missing.append(f'{source.name}: {page} {anchor or quoted!r}')
    assert cited >= 10
    assert not missing, missing


def test_the_diagnosis_json_names_its_schema():
    from aeropend_core.diagnosis.diagnose import DIAGNOSIS_SCHEMA, Diagnosis
    import inspect
    assert DIAGNOSIS_SCHEMA == 'aeropend.diagnosis/1'
    # to_dict (what --json prints) is numbers_dict with the verdict's words; the schema is its first key
    assert "'schema': DIAGNOSIS_SCHEMA" in inspect.getsource(Diagnosis.numbers_dict)
    assert 'diagnosis_dict(self)' in inspect.getsource(Diagnosis.to_dict)


@pytest.mark.slow
def test_a_current_recorded_in_the_wrong_scale_is_doubted_beside_ra(tmp_path, capsys):
    """22 s of the default rig with the current divided by 2.963 (ADC counts read as mA on the paper's wiring):
    Ra comes out ~3.2 ohm for a truth of 1.08 and a DOUBT stands beside it, in a note and in the JSON; the same
    record in amperes raises none. The diagnosis's JSON names its schema."""
    from aeropend_core.io.recording import write_csv
    from aeropend_core.sim.excitation import lhc_schedule
    from aeropend_core.sim.noise import MeasurementNoise
    from aeropend_core.sim.simulate import simulate
    duty = lhc_schedule(22.0, seed=5).duty(duration=22.0)
    run = simulate(duty, noise=MeasurementNoise(40.0, True), seed=5)
    columns = {k: np.asarray(v, float) for k, v in run.columns(with_truth=False).items()
               if k in ('t', 'duty', 'armature_voltage', 'armature_current', 'angle')}
    results = {}
    for scale in (1.0, 2.963):
        path = tmp_path / f'scale{scale}.csv'
        write_csv(str(path), {**columns, 'armature_current': columns['armature_current'] / scale})
        status, out, err = call(capsys, 'diagnose', str(path), '--quiet', '--no-drift', '--no-discovery', '--only',
                                'angle_offset', '--json', str(tmp_path / f'{scale}.json'))
        assert status == 0, err
        results[scale] = (out, json.loads((tmp_path / f'{scale}.json').read_text()))
    out, data = results[2.963]
    assert data['schema'] == 'aeropend.diagnosis/1'
    assert data['parameters']['armature_resistance'] == pytest.approx(1.08 * 2.963, rel=0.05)
    assert 'DOUBT' in data['parameter_doubts']['armature_resistance']
    ra_line = next(line for line in out.splitlines() if line.strip().startswith('armature_resistance'))
    assert 'DOUBT' in ra_line and 'current' in ra_line
    out, data = results[1.0]
    assert data['parameter_doubts'] == {} and 'DOUBT' not in out


def test_aeropend_error_is_what_the_refusals_raise():
    """The refusals above are user mistakes (exit 2), never bugs."""
    from aeropend_core.io.profile_guess import foreign_log_error
    assert isinstance(foreign_log_error('x.csv', 'no header'), AeropendError)

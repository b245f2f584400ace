"""Damaged bags: readers go past a bad chunk and say what they lost; bag-recover keeps everything the ``mcap``
package can still decode, writes a new bag, and cannot lose a recording that starts while it runs.

A fast subset of the mutation suite (``bench/bag_mutations.py`` runs 560 cases of 14 operators) with the same
judge: every message the ``mcap`` package decodes chunk by chunk from the damaged file must be in the recovered one.
"""
from __future__ import annotations

import json
import random
import struct
import subprocess
import sys
import warnings
import zlib
from pathlib import Path

import numpy as np
import pytest

from aeropend_core.errors import AeropendError
from aeropend_core.io.bag import SampleDamage, read_samples
from aeropend_core.io.bag_recover import recover_bag
from aeropend_core.io.recording import bag_findings
from aeropend_core.testing.bag_mutations import OPERATORS, judge_messages, layout, message_keys, write_sample_bag

ROOT = Path(__file__).resolve().parents[1]
AEROPEND = [sys.executable, '-c', 'import sys; from aeropend_core.cli import main; sys.exit(main())']
N = 1200


@pytest.fixture(scope='module')
def originals(tmp_path_factory):
    folder = tmp_path_factory.mktemp('originals')
    out = {}
    for crcs in (True, False):
        data = write_sample_bag(folder / f'o_{crcs}.mcap', N, chunk_size=8 * 1024, crcs=crcs).read_bytes()
        out[crcs] = (data, layout(data))
    return out


def stream_messages(path: Path) -> set:
    from mcap.records import Message
    from mcap.stream_reader import StreamReader
    with open(path, 'rb') as stream:
        return message_keys(r for r in StreamReader(stream, validate_crcs=True).records if isinstance(r, Message))


def read_with_damage(path: Path) -> tuple[dict, list[SampleDamage]]:
    damage: list[SampleDamage] = []
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        return read_samples(path, damage=damage), damage


@pytest.mark.parametrize('operator', ['crc_flip', 'data_flip', 'truncate', 'opcode_footer', 'opcode_unknown',
                                      'chunk_reorder', 'duplicate_chunk', 'chunk_length', 'summary_removed',
                                      'summary_damaged', 'zero_block', 'insert_garbage', 'no_crc_flip'])
@pytest.mark.parametrize('seed', [1, 2])
def test_recover_keeps_all_the_judge_decodes_and_a_partial_read_is_never_clean(tmp_path, originals, operator,
                                                                                seed):
    crcs = operator != 'no_crc_flip'
    data, lay = originals[crcs]
    damaged = OPERATORS[operator](data, lay, random.Random(seed))
    path = tmp_path / 'damaged.mcap'
    path.write_bytes(damaged)
    judged = judge_messages(damaged)
    report = recover_bag(path)
    assert path.read_bytes() == damaged, 'the original was changed'
    out = tmp_path / 'damaged_recovered.mcap'
    recovered = stream_messages(out) if report.repaired else stream_messages(path)
    assert judged <= recovered, f'{len(judged - recovered)} decodable messages lost'
    samples, damage = read_with_damage(path)
    findings = bag_findings(path, damage)
    if len(samples['sequence']) < N or not crcs:
        assert findings, 'a partial read without a finding would say "clean"'
    if operator == 'chunk_reorder':               # valid MCAP: read in time order, nothing lost
        np.testing.assert_array_equal(samples['sequence'], np.arange(N))
    dropped = [c for c in report.chunks if not c.kept]
    if operator in ('crc_flip', 'data_flip'):     # exactly one chunk dropped, the loss located and counted
        assert len(dropped) == 1, report.chunks
        lost = [d for d in damage if d.damage.lost]
        assert len(lost) == 1 and lost[0].samples == N - len(samples['sequence']) > 0, [d.line() for d in damage]
        assert lost[0].t_start < lost[0].t_stop


def test_chunks_without_crc_are_said_and_a_summary_that_disagrees_is_a_finding(tmp_path, originals):
    data, lay = originals[False]
    path = tmp_path / 'nocrc.mcap'
    path.write_bytes(data)
    samples, damage = read_with_damage(path)
    assert len(samples['sequence']) == N
    findings = bag_findings(path, damage)
    assert any(f.code == 'bag_no_crc' and 'this bag has no CRCs: bit flips cannot be detected' in f.message
               for f in findings), findings

    data, lay = originals[True]
    start, _, end = lay.chunks[3]
    # a whole chunk cut out; the summary still counts it, and its offsets and CRC are made right again
    removed = bytearray(data[:start] + data[end:])
    footer = len(removed) - 8 - 29
    summary_start, offset_start, _ = struct.unpack_from('<QQI', removed, footer + 9)
    struct.pack_into('<QQ', removed, footer + 9, summary_start - (end - start), offset_start - (end - start))
    struct.pack_into('<I', removed, footer + 25, zlib.crc32(removed[summary_start - (end - start):footer + 25]))
    path = tmp_path / 'short.mcap'
    path.write_bytes(bytes(removed))
    samples, damage = read_with_damage(path)
    codes = {f.code for f in bag_findings(path, damage)}
    assert 'bag_summary_mismatch' in codes and len(samples['sequence']) < N, codes


def test_recover_report_per_chunk_and_in_place_replacement(tmp_path, originals):
    data, lay = originals[True]
    damaged = OPERATORS['crc_flip'](data, lay, random.Random(5))
    path = tmp_path / 'x.mcap'
    path.write_bytes(damaged)
    result = subprocess.run([*AEROPEND, 'bag-recover', str(path), '--json', '-'], capture_output=True, text=True,
                            cwd=ROOT, timeout=120, check=False)
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    kept = [c for c in report['chunks'] if c['kept']]
    dropped = [c for c in report['chunks'] if not c['kept']]
    assert len(kept) == len(lay.chunks) - 1 and len(dropped) == 1, report['chunks']
    assert dropped[0]['messages'] > 0 and 'CRC mismatch' in dropped[0]['reason']
    assert 'dropped x.mcap byte' in result.stderr and 'original is unchanged' in result.stderr
    assert path.read_bytes() == damaged and Path(report['output']).name == 'x_recovered.mcap'
    # a second run refuses to overwrite the first result
    again = subprocess.run([*AEROPEND, 'bag-recover', str(path)], capture_output=True, text=True, cwd=ROOT,
                           timeout=120, check=False)
    assert again.returncode == 2 and 'exists already' in again.stderr and 'Traceback' not in again.stderr

    recover_bag(path, in_place=True, keep_original=True)
    assert (tmp_path / 'x.mcap.orig').read_bytes() == damaged
    assert stream_messages(path) == stream_messages(tmp_path / 'x_recovered.mcap')
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        fixed = read_samples(path, on_incomplete='raise')['sequence']
    assert N - dropped[0]['messages'] <= len(fixed) < N
    with pytest.raises(AeropendError, match='--in-place or --output'):
        recover_bag(path, in_place=True, output=tmp_path / 'y.mcap')


@pytest.mark.slow
def test_identify_on_a_damaged_bag_reads_past_the_chunk_and_says_what_is_lost(tmp_path):
    """The identify verb: the rest of the bag is used, the text never says 'clean', the JSON warnings hold the
    lost span and sample count."""
    from mcap.reader import make_reader

    from aeropend_core.io.bag_writer import BagWriter
    from aeropend_core.sim.excitation import lhc_schedule
    from aeropend_core.sim.simulate import simulate
    from tests.test_bag import SAMPLES, cdr_joint_state, write_bag
    run = simulate(lhc_schedule(30.0, seed=4).duty(duration=30.0), seed=4)
    columns = run.columns(with_truth=False)
    folder = tmp_path / 'sim'
    writer: BagWriter = write_bag(folder, 0, chunk_size=16 * 1024)
    for k in range(len(columns['t'])):
        stamp = 1_763_700_000_000_000_000 + round(columns['t'][k] * 1e9)
        values = [columns[name][k] for name in ('angle', 'armature_voltage', 'armature_current', 'duty')]
        writer.write(SAMPLES, cdr_joint_state(stamp, [*values, float(k)]), log_time_ns=stamp, sequence=k + 1)
    writer.finish()
    file = folder / 'sim_0.mcap'
    data = bytearray(file.read_bytes())
    with open(file, 'rb') as stream:
        chunks = sorted(make_reader(stream).get_summary().chunk_indexes, key=lambda c: c.chunk_start_offset)
    bad = chunks[len(chunks) // 2]
    data[bad.chunk_start_offset + 9 + 24] ^= 0xFF                 # its CRC field only: the data are intact
    file.write_bytes(bytes(data))
    # --weak-only: the promise is how the damaged bag is read and said; the cross-check it skips reads nothing more
    result = subprocess.run([*AEROPEND, 'identify', str(folder), '--json', str(tmp_path / 'out.json'), '--weak-only'],
                            capture_output=True, text=True, cwd=ROOT, timeout=300, check=False)
    assert result.returncode == 0, result.stderr
    text = result.stdout + result.stderr
    assert 'Data quality: clean' not in text and 'bag_damaged' in text, text
    warnings_json = json.loads((tmp_path / 'out.json').read_text())['warnings']
    damaged = [w for w in warnings_json if w['code'] == 'bag_damaged']
    assert len(damaged) == 1 and damaged[0]['count'] > 0 and damaged[0]['where'][0] < damaged[0]['where'][1]
    assert 'CRC mismatch' in damaged[0]['message'] and 'sample(s) lost between' in damaged[0]['message']


@pytest.mark.timeout(600)
def test_recover_racing_a_starting_recorder_loses_no_recording(tmp_path):
    """bag-recover --in-place called in a tight loop on the folder a recorder is starting to write: every
    recording is complete (bench/bag_recover_race.py runs 30 of these)."""
    from aeropend_ros.testing import private_domain_id, recover_race
    from tests.ros_helpers import NodeProcess
    domain = private_domain_id()
    with NodeProcess('aeropend_ros.sim_node', ['-p', 'psnr_db:=40.0'], domain) as sim:
        for trial in range(3):
            result = recover_race(tmp_path / f'race_{trial}', domain, record_seconds=1.0)
            assert not result['lost'], (result, sim.output()[-2000:])
            assert result['attempts'] > 0 and result['read'] > 0

"""Issue 43: readers and recovery resume after any record they cannot parse, skip what is bad, keep every decodable
sample and say what they skipped; a gap near the end of a record is fitted around, never a refusal.

The damaged bags are ``bags/sample_sim`` with one byte changed, as in the issue:

* byte 124635 (a message index's type 0x07) set to 0x0f (data end): before, 2,543 of 9,185 samples were read and the
  read stopped there, calling t = 5.19 s "the end of the record";
* byte 348500 (a message index's type) set to 0x05 (message): before, the whole bag was refused ("not valid CDR for
  JointState") and ``bag-recover`` wrote the junk message, which the ``rosbags`` reader then could not read;
* chunk 28 of 29 with a damaged CRC: before, ``identify`` refused the record ("time is not uniformly sampled").
"""
from __future__ import annotations

import shutil
import struct
import warnings
from pathlib import Path

import numpy as np
import pytest

from aeropend_core import cli
from aeropend_core.io.bag import read_samples
from aeropend_core.io.bag_recover import recover_bag
from aeropend_core.io.recording import load_recording
from tests.test_bag import SAMPLES, T0_NS, TS_NS, cdr_joint_state, sample_values, write_bag

REPO = Path(__file__).resolve().parents[1]
SAMPLE_BAG = REPO / 'bags' / 'sample_sim'
ALL_SAMPLES = 9185


def damaged_copy(tmp_path: Path, offset: int, value: int, expected: int = 0x07) -> Path:
    folder = tmp_path / 'bag'
    shutil.copytree(SAMPLE_BAG, folder)
    file = next(folder.glob('*.mcap'))
    data = bytearray(file.read_bytes())
    assert data[offset] == expected, f'byte {offset} of the sample bag is 0x{data[offset]:02x}, not 0x{expected:02x}'
    data[offset] = value
    file.write_bytes(bytes(data))
    return folder


def chunk_offsets(file: Path) -> list[int]:
    data = file.read_bytes()
    position, found = 8, []
    while position + 9 <= len(data) and data[position] != 0x0F:
        if data[position] == 0x06:
            found.append(position)
        position += 9 + struct.unpack_from('<Q', data, position + 1)[0]
    return found


def independent_count(folder: Path) -> int:
    from rosbags.highlevel import AnyReader
    count = 0
    with AnyReader([folder]) as reader:
        connections = [c for c in reader.connections if c.topic == SAMPLES]
        for connection, _, raw in reader.messages(connections=connections):
            reader.deserialize(raw, connection.msgtype)
            count += 1
    return count


def quiet_samples(path: Path, damage: list | None = None) -> dict:
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        return read_samples(path, damage=damage)


def test_a_data_end_type_byte_in_the_middle_does_not_end_the_read(tmp_path):
    bag = damaged_copy(tmp_path, 124635, 0x0F)
    damage: list = []
    samples = quiet_samples(bag, damage)
    assert len(samples['time']) == ALL_SAMPLES == independent_count(bag)
    assert [d.damage.kind for d in damage] == ['repaired_in_place'] and not damage[0].damage.lost
    report = recover_bag(bag)
    assert report.message_count == 9238 and independent_count(report.folder) == ALL_SAMPLES


def test_an_undecodable_message_is_skipped_and_never_recovered(tmp_path):
    bag = damaged_copy(tmp_path, 348500, 0x05)
    damage: list = []
    samples = quiet_samples(bag, damage)
    assert len(samples['time']) == ALL_SAMPLES
    skipped = [d for d in damage if d.damage.kind == 'undecodable']
    assert len(skipped) == 1 and skipped[0].damage.messages == 1 and skipped[0].samples == 0
    recording = load_recording(bag)            # not refused; the skipped message is a finding
    assert len(recording) == ALL_SAMPLES and any('not decodable' in f.message for f in recording.findings)
    report = recover_bag(bag)
    assert any(not o.kept and o.messages == 1 for o in report.chunks)
    assert independent_count(report.folder) == ALL_SAMPLES          # before: rosbags failed on the junk message


def test_a_stamp_out_of_order_is_skipped_with_a_report(tmp_path):
    folder = tmp_path / 'stamps'
    writer = write_bag(folder, 0)
    n, wrong = 2000, 700
    for k in range(n):
        stamp = T0_NS + k * TS_NS
        written = stamp + 7_000_000_000 if k == wrong else stamp     # one stamp damaged: 7 s late
        writer.write(SAMPLES, cdr_joint_state(written, sample_values(k)), log_time_ns=stamp + 300_000,
                     sequence=k + 1)
    writer.finish()
    damage: list = []
    samples = quiet_samples(folder, damage)
    assert len(samples['time']) == n - 1 and np.all(np.diff(samples['time']) > 0)
    assert wrong not in samples['sequence'].tolist()
    skipped = [d for d in damage if d.damage.kind == 'stamp_out_of_order']
    assert len(skipped) == 1 and skipped[0].damage.messages == 1
    assert skipped[0].t_start == pytest.approx((wrong - 1) * TS_NS * 1e-9)
    recording = load_recording(folder)          # before: "time stamps go backwards ... sort them by time"
    assert len(recording) == n - 1


def test_a_lost_chunk_near_the_end_is_fitted_around(tmp_path, capsys, monkeypatch):
    monkeypatch.delenv('AEROPEND_DEBUG', raising=False)
    folder = tmp_path / 'bag'
    shutil.copytree(SAMPLE_BAG, folder)
    file = next(folder.glob('*.mcap'))
    chunks = chunk_offsets(file)
    assert len(chunks) == 29
    data = bytearray(file.read_bytes())
    data[chunks[27] + 9 + 24] ^= 0xFF                      # chunk 28's CRC field
    file.write_bytes(bytes(data))
    status = cli.main(['identify', str(folder)])
    captured = capsys.readouterr()
    assert status == 0, captured.err
    assert 'not uniformly sampled' not in captured.err
    assert 'shorter than 1 s, not fitted' in captured.err


@pytest.mark.parametrize('operator', ['index_opcode_data_end', 'index_opcode_message', 'index_opcode_unknown',
                                      'crc_flip_near_end', 'stamp_flip', 'message_flip'])
def test_new_mutations_read_at_least_what_rosbags_reads(tmp_path, operator):
    """The issue 43 operators of the mutation bench, one seed each: our reader keeps every sample the independent
    reader decodes (or reports the one it skipped), the recovered file reads no worse for rosbags, and what identify
    reads (the data-quality gate) is not refused."""
    import random

    from aeropend_core.testing.bag_mutations import NEEDS, OPERATORS, layout, write_sample_bag
    crcs, compression = NEEDS.get(operator, (True, 'zstd'))
    original = write_sample_bag(tmp_path / 'original.mcap', 1200, chunk_size=8 * 1024, crcs=crcs,
                                compression=compression)
    data = original.read_bytes()
    path = tmp_path / 'damaged.mcap'
    path.write_bytes(OPERATORS[operator](data, layout(data), random.Random(1)))

    def rosbags_count(file: Path) -> int:
        from rosbags.highlevel import AnyReader
        count = 0
        try:
            with AnyReader([file]) as reader:
                connections = [c for c in reader.connections if c.topic == SAMPLES]
                for connection, _, raw in reader.messages(connections=connections):
                    reader.deserialize(raw, connection.msgtype)
                    count += 1
        except Exception:       # noqa: BLE001 - its first error ends its count
            pass
        return count

    damage: list = []
    samples = quiet_samples(path, damage)
    skipped = sum(d.damage.messages or 0 for d in damage if d.damage.kind in ('undecodable', 'stamp_out_of_order'))
    independent = rosbags_count(path)
    assert len(samples['time']) + skipped >= independent
    report = recover_bag(path)
    recovered = tmp_path / 'damaged_recovered.mcap'
    assert rosbags_count(recovered if recovered.exists() else path) >= independent, report.notes
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        assert len(load_recording(path)) >= 0.9 * 1200        # not refused


def test_bytes_inserted_in_the_first_chunk_keep_the_definitions_of_the_summary(tmp_path):
    """Garbage inserted inside the first chunk (the one with the schemas and channels) shifts the summary away from
    where the footer says it is: it is found after the data-end record (its CRC still matches), so the messages of
    every other chunk keep their topic; before, the bag was refused as holding no sample (mutation insert_garbage,
    seed 31 of --per-operator 40)."""
    from aeropend_core.testing.bag_mutations import layout, write_sample_bag
    data = write_sample_bag(tmp_path / 'original.mcap', 1200, chunk_size=8 * 1024).read_bytes()
    at = layout(data).chunks[0][0] + 60                 # inside the first chunk's data
    path = tmp_path / 'garbage.mcap'
    path.write_bytes(data[:at] + bytes(range(100)) + data[at:])
    damage: list = []
    samples = quiet_samples(path, damage)
    assert 1000 < len(samples['time']) < 1200
    assert any(d.damage.kind == 'summary_mismatch' and 'starts at byte' in d.damage.detail for d in damage)
    recover_bag(path)
    from rosbags.highlevel import AnyReader
    with AnyReader([tmp_path / 'garbage_recovered.mcap']) as reader:
        assert sum(1 for c in reader.connections if c.topic == SAMPLES) == 1
        assert sum(1 for _ in reader.messages(connections=[c for c in reader.connections
                                                             if c.topic == SAMPLES])) == len(samples['time'])

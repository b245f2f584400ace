"""Issue 43: the bag writer closes the chunk in progress on time as well as on size, so a SIGKILL loses at most
about ``max_chunk_duration`` of the recording (before: the 256 KiB chunk in progress, up to 2.5 s at 490 Hz).
"""
from __future__ import annotations

import warnings

import pytest

from aeropend_core.io import bag_writer
from aeropend_core.io.bag import read_samples
from tests.test_bag import SAMPLES, T0_NS, TS_NS, cdr_joint_state, sample_values, write_bag


class Clock:
    def __init__(self):
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture
def clock(monkeypatch):
    fake = Clock()
    monkeypatch.setattr(bag_writer.time, 'monotonic', fake)
    return fake


def write_samples(writer, first: int, count: int) -> None:
    for k in range(first, first + count):
        stamp = T0_NS + k * TS_NS
        writer.write(SAMPLES, cdr_joint_state(stamp, sample_values(k)), log_time_ns=stamp, sequence=k + 1)


def on_disk_now(folder) -> int:
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        return len(read_samples(folder)['time'])


def test_the_chunk_in_progress_goes_to_disk_on_time(tmp_path, clock):
    folder = tmp_path / 'bag'
    writer = write_bag(folder, 0, chunk_size=1024 * 1024, max_chunk_duration=0.5)
    write_samples(writer, 0, 100)
    assert writer.messages_on_disk == 0                  # a 1 MiB chunk is far from full
    clock.now += 0.4
    writer.tick()
    assert writer.messages_on_disk == 0
    clock.now += 0.2                                     # 0.6 s since the chunk's first message
    writer.tick()                                        # no message came: the tick closes it
    assert writer.messages_on_disk == 100 and on_disk_now(folder) == 100
    write_samples(writer, 100, 50)
    clock.now += 0.5
    write_samples(writer, 150, 1)                        # a message past the deadline closes it too
    assert writer.messages_on_disk == 151 and on_disk_now(folder) == 151
    writer.finish()
    assert len(read_samples(folder, on_incomplete='raise')['time']) == 151


def test_size_only_when_no_duration(tmp_path, clock):
    writer = write_bag(tmp_path / 'bag', 0, chunk_size=1024 * 1024)
    write_samples(writer, 0, 100)
    clock.now += 100.0
    writer.tick()
    assert writer.messages_on_disk == 0
    writer.finish()

"""Serial frame decoder throughput (target >= 200,000 frames/s, 400x the rig's 490 Hz).

Decodes a stream of SAMPLE frames (19 bytes each on the wire) fed in 4 kB reads, like a serial port, with
aeropend_core.rig.protocol.FrameDecoder. Baselines measured in the same run on the same bytes:

* naive: the textbook decoder, one byte at a time through a state machine (append until 0x00, COBS decode, CRC,
  unpack): what a straightforward port of the firmware's receive loop to Python does;
* scan: bytes.split on the delimiter alone, no decoding (an upper bound: the cost of just finding the frames).

A second stream with 30 % of its bytes garbage (random, bit flips, truncations) checks that throughput holds when
resynchronising.

Run:  .venv/bin/python bench/bench_decoder.py [--frames 200000] [--repeat 3] [--json PATH]   (~6 s)
"""
from __future__ import annotations

import argparse
import random
import struct
import time

from _common import add_json_argument, figure, write_json

from aeropend_core.rig import protocol as P

TARGET = 200_000
RIG_RATE = 1 / P.SAMPLE_PERIOD


def make_stream(n_frames: int, garbage_fraction: float = 0.0, seed: int = 0) -> tuple[bytes, int]:
    rng = random.Random(seed)
    parts = []
    garbage = 0
    for sequence in range(n_frames):
        if garbage_fraction and rng.random() < garbage_fraction * 2:
            blob = rng.randbytes(rng.randrange(1, 20))
            parts.append(blob)
            garbage += len(blob)
        parts.append(P.encode_sample(P.SampleFrame(sequence, rng.randrange(1024), rng.randrange(1024),
                                                   rng.randrange(1024), rng.randrange(65536), 0)))
    return b''.join(parts), garbage


class NaiveDecoder:
    """Byte-at-a-time state machine (baseline)."""

    def __init__(self) -> None:
        self.buffer = bytearray()
        self.corrupt = 0

    def feed(self, data: bytes) -> list:
        out = []
        for byte in data:
            if byte != 0:
                self.buffer.append(byte)
                continue
            if not self.buffer:
                continue
            try:
                payload = P.cobs_decode(bytes(self.buffer))
                body, crc = payload[:-2], struct.unpack('<H', payload[-2:])[0]
                if P.crc16(body) != crc or body[0] != P.SAMPLE or len(body) != 14:
                    raise P.ProtocolError('bad frame')
                out.append(P.SampleFrame(*struct.unpack('<BIHHHHB', body)[1:]))
            except (P.ProtocolError, struct.error, IndexError):
                self.corrupt += 1
            self.buffer.clear()
        return out


def scan(data: bytes) -> int:
    return sum(1 for chunk in data.split(b'\x00') if chunk)


def timed(function, repeat: int) -> tuple[float, object]:
    best = float('inf')
    result = None
    for _ in range(repeat):
        start = time.perf_counter()
        result = function()
        best = min(best, time.perf_counter() - start)
    return best, result


def feed_all(decoder, data: bytes, read_size: int = 4096) -> int:
    count = 0
    for index in range(0, len(data), read_size):
        count += len(decoder.feed(data[index:index + read_size]))
    return count


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--frames', type=int, default=200_000)
    parser.add_argument('--repeat', type=int, default=3)
    add_json_argument(parser)
    args = parser.parse_args()

    clean, _ = make_stream(args.frames)
    dirty, garbage = make_stream(args.frames, garbage_fraction=0.3, seed=1)
    n = args.frames
    print(f'{n} SAMPLE frames, {len(clean) / n:.0f} bytes each on the wire, read in 4 kB chunks; '
          f'best of {args.repeat}')

    fast_time, fast_count = timed(lambda: feed_all(P.FrameDecoder(), clean), args.repeat)
    naive_time, naive_count = timed(lambda: feed_all(NaiveDecoder(), clean), max(1, args.repeat - 2))
    scan_time, scan_count = timed(lambda: scan(clean), args.repeat)
    assert fast_count == naive_count == scan_count == n, (fast_count, naive_count, scan_count)
    fast_rate = n / fast_time
    print(f'FrameDecoder        {fast_rate:12,.0f} frames/s  ({fast_rate / RIG_RATE:,.0f}x the rig rate; '
          f'target {TARGET:,}: {"met" if fast_rate >= TARGET else "NOT met"})')
    print(f'naive (per byte)    {n / naive_time:12,.0f} frames/s  -> FrameDecoder is {naive_time / fast_time:.1f}x '
          f'faster')
    print(f'scan only (split)   {n / scan_time:12,.0f} chunks/s  -> FrameDecoder costs {fast_time / scan_time:.1f}x '
          f'a bare delimiter scan')

    dirty_time, dirty_count = timed(lambda: feed_all(P.FrameDecoder(), dirty), args.repeat)
    assert dirty_count == n, dirty_count
    print(f'with {garbage / len(dirty):.0%} garbage bytes: {n / dirty_time:,.0f} frames/s '
          f'(every intact frame recovered)')
    write_json(args.json, 'bench_decoder', [
        figure('bridge frame decoder throughput', fast_rate, 'frames/s', baseline=n / naive_time,
               baseline_name='naive byte-at-a-time decoder', ratio=naive_time / fast_time,
               ratio_meaning='speed-up (baseline time / ours)', target=f'>= {TARGET:,} frames/s',
               met=fast_rate >= TARGET),
        figure(f'decoder throughput, stream with {garbage / len(dirty):.0%} garbage bytes', n / dirty_time,
               'frames/s', baseline=fast_rate, baseline_name='clean stream', ratio_meaning='garbage / clean'),
        figure('decoder cost vs bare delimiter scan', fast_time * 1e9 / n, 'ns/frame', baseline=scan_time * 1e9 / n,
               baseline_name='bytes.split on the delimiter (no decoding)', ratio_meaning='ours / scan'),
    ], frames=n, repeat=args.repeat, rig_rate_hz=RIG_RATE, garbage_byte_fraction=garbage / len(dirty))
    return 0 if fast_rate >= TARGET else 1


if __name__ == '__main__':
    raise SystemExit(main())

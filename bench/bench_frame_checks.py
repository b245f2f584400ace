"""Residual error rate of the serial link: damaged SAMPLE frames that pass CRC-16, and those that also pass the
range and sequence checks (aeropend_core.rig.link_checks.FrameChecker).

Each trial sends three frames of one stream, numbered s-1, s, s+1 (random 10-bit counts, random duty), and damages
the middle one on the wire (COBS bytes between the delimiters) by one of these models:

* ``bits``: 2..16 random bit flips anywhere in the frame (1 flip is always caught by a CRC);
* ``burst``: 1..8 consecutive bytes replaced by random bytes (a glitch on the line);
* ``random``: the whole frame replaced by random non-zero bytes of the right length (garbage that looks framed).

With ``--forge`` the damage is applied to the 14-byte payload and the frame is re-encoded with a *valid* CRC: every
damaged frame then passes CRC-16 (a CRC miss by construction), which measures what the range and sequence checks
catch on their own. The residual rate is about P(CRC-16 misses) x P(checks miss).

The stream goes through FrameDecoder and then FrameChecker exactly as in the bridge. Counted per model: frames the
CRC let through with contents different from what was sent (``crc_pass``), and those that the checks also accepted
(``published``: what a subscriber would receive as true). The rates are per damaged frame; a link with a bit error
rate b damages about 150 b frames per second at 490 Hz.

Run:  .venv/bin/python bench/bench_frame_checks.py [--trials 1000000] [--seed 1] [--json PATH]
      (~2 min per 10^6 trials and model on this machine; run with nice)
"""
from __future__ import annotations

import argparse
import math
import random
import time

from _common import add_json_argument, figure, write_json

from aeropend_core.rig import protocol as P
from aeropend_core.rig.link_checks import FrameChecker

MODELS = ('bits', 'burst', 'random')


def damage(wire: bytes, model: str, rng: random.Random) -> bytes:
    """`wire` (one frame without delimiters) damaged by `model`; zero bytes created inside split it, as on a link."""
    data = bytearray(wire)
    if model == 'bits':
        for bit in rng.sample(range(8 * len(data)), rng.randint(2, 16)):
            data[bit // 8] ^= 1 << (bit % 8)
    elif model == 'burst':
        length = rng.randint(1, 8)
        start = rng.randrange(0, len(data) - length + 1)
        data[start:start + length] = rng.randbytes(length)
    else:
        data = bytearray(rng.randrange(1, 256) for _ in range(len(data)))
    return bytes(data)


def forge(frame: P.SampleFrame, model: str, rng: random.Random) -> bytes:
    """The frame's payload damaged by `model`, re-encoded with a valid CRC (COBS bytes, no delimiters)."""
    payload = bytearray(P.encode_sample(frame)[1:-1])
    payload = bytearray(P.cobs_decode(bytes(payload))[:-2])
    body = bytearray(payload[1:])                       # keep the type byte: a SAMPLE
    body = bytearray(damage(bytes(body), model, rng)) if model != 'random' else bytearray(rng.randbytes(len(body)))
    return P.frame(bytes([P.SAMPLE]) + bytes(body))[1:-1]


def run(model: str, trials: int, seed: int, forged: bool = False) -> dict[str, float]:
    rng = random.Random(seed)
    decoder = P.FrameDecoder()
    checker = FrameChecker()
    decoder.feed(b'\x00')
    base = rng.randrange(0, 1 << 31)
    crc_pass = published = 0
    previous: set = set()           # a held sample comes out with the next trial's frames
    start = time.perf_counter()
    for trial in range(trials):
        sequence = base + 3 * trial
        frames = [P.SampleFrame(sequence + k, rng.randrange(1024), rng.randrange(1024), rng.randrange(1024),
                                rng.randrange(65536), 0) for k in range(3)]
        wires = [P.encode_sample(frame)[1:-1] for frame in frames]
        middle = forge(frames[1], model, rng) if forged else damage(wires[1], model, rng)
        stream = (wires[0] + b'\x00' + middle + b'\x00' + wires[2] + b'\x00')
        decoded = decoder.feed(stream)
        sent = set(frames)
        crc_pass += sum(1 for frame in decoded if frame not in sent)
        for checked in checker.check(decoded):
            if checked.frame not in sent and checked.frame not in previous:
                published += 1
        previous = sent
    seconds = time.perf_counter() - start
    return {'trials': trials, 'crc_pass': crc_pass, 'published': published, 'seconds': seconds}


def upper_95(count: int, trials: int) -> float:
    """One-sided 95 % upper bound of a rate from `count` events in `trials` (exact for 0: 3/n; else Poisson)."""
    if count == 0:
        return 3.0 / trials
    # Wilson-Hilferty approximation of the Poisson upper bound.
    k = count + 1
    return k * (1 - 1 / (9 * k) + 1.645 / (3 * math.sqrt(k))) ** 3 / trials


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--trials', type=int, default=1_000_000, help='damaged frames per model (default 10^6)')
    parser.add_argument('--seed', type=int, default=1)
    parser.add_argument('--models', nargs='+', default=list(MODELS), choices=MODELS)
    parser.add_argument('--forge', action='store_true', help='damage the payload and re-encode it with a valid CRC '
                        '(what the range and sequence checks catch on their own)')
    add_json_argument(parser)
    args = parser.parse_args()
    figures = []
    details = {}
    print(f'{"model":8} {"trials":>9} {"CRC-16 passed":>14} {"rate":>10} {"published":>10} {"rate (95 % up)":>15}')
    for index, model in enumerate(args.models):
        result = run(model, args.trials, args.seed + index, args.forge)
        details[model] = result
        crc_rate = result['crc_pass'] / result['trials']
        print(f'{model:8} {result["trials"]:9d} {result["crc_pass"]:14d} {crc_rate:10.2e} {result["published"]:10d} '
              f'{upper_95(result["published"], result["trials"]):15.2e}   ({result["seconds"]:.0f} s)')
        figures.append(figure(f'{model}_crc16_pass_rate', crc_rate, 'per damaged frame'))
        figures.append(figure(f'{model}_published_rate_upper95', upper_95(result['published'], result['trials']),
                              'per damaged frame'))
    write_json(args.json, 'frame_checks', figures, **details)


if __name__ == '__main__':
    main()

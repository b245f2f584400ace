"""The schedules the experiment design searches (:mod:`aeropend_core.diagnosis.experiment_design`): random block
schedules (duty steps, rests at duty 0, sine sweeps, square waves), the structured ones every search starts with,
and the local changes that refine the best. Durations in s, duties as fractions.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from aeropend_core.sim.schedule_file import SWEEP_HOLD, Block

#: Rest at duty 0 at the start of every design [s] (the rod starts hanging still, as the models assume).
LEAD_REST = 1.0


def _random_blocks(rng: np.random.Generator, duration: float, duty_limit: float) -> tuple[Block, ...]:
    """A random schedule: 3-7 blocks (steps, rests, sweeps, square waves) filling `duration` [s] after the lead rest."""
    count = int(rng.integers(3, 8))
    shares = rng.dirichlet(np.full(count, 2.0))
    available = duration - LEAD_REST
    blocks = [Block('rest', LEAD_REST)]
    for share in shares:
        seconds = max(0.5, round(float(share * available) / SWEEP_HOLD) * SWEEP_HOLD)
        blocks.append(_random_block(rng, seconds, duty_limit))
    return _fit_duration(tuple(blocks), duration)


def _random_block(rng: np.random.Generator, seconds: float, duty_limit: float) -> Block:
    kind = rng.choice(['step', 'rest', 'sweep', 'square'], p=[0.35, 0.2, 0.2, 0.25])
    if kind == 'rest':
        return Block('rest', seconds)
    if kind == 'step':
        return Block('step', seconds, level=float(rng.uniform(0.1, 1.0) * duty_limit))
    mean = float(rng.uniform(0.2, 0.8) * duty_limit)
    amplitude = float(rng.uniform(0.2, 1.0) * min(mean, duty_limit - mean))
    low, high = sorted(rng.uniform(0.3, 4.0, size=2))
    return Block(str(kind), seconds, level=mean, amplitude=amplitude, start_hz=float(low), stop_hz=float(high))


def _structured_blocks(duration: float, duty_limit: float) -> list[tuple[Block, ...]]:
    """Schedules every search starts with: square waves over the whole duty range (the largest, fastest swings: what
    separates effects that differ only through the nonlinearities, bench/results/2026-11-27-s8-loop2), and steps
    up to the limit with rests at duty 0 between them (the offset is read at rest; large angles)."""
    available = duration - LEAD_REST
    half = 0.5 * duty_limit
    squares = [(Block('rest', LEAD_REST), Block('square', available, half, half, hz, hz)) for hz in (0.5, 1.0)]
    dwell = available / 6
    stairs = (Block('rest', LEAD_REST),) + tuple(
        block for level in (0.4, 0.7, 1.0) for block in (Block('step', dwell, level=level * duty_limit),
                                                         Block('rest', dwell)))
    return [_fit_duration(blocks, duration) for blocks in squares + [stairs]]


def _fit_duration(blocks: tuple[Block, ...], duration: float) -> tuple[Block, ...]:
    """Stretch or cut the last block so that the blocks last exactly `duration` [s]."""
    total = sum(b.seconds for b in blocks)
    last = blocks[-1]
    seconds = max(SWEEP_HOLD, last.seconds + duration - total)
    return blocks[:-1] + (replace(last, seconds=seconds),)


def _mutate(blocks: tuple[Block, ...], rng: np.random.Generator, duration: float,
            duty_limit: float) -> tuple[Block, ...]:
    """One local change: a block's level, amplitude, frequencies or length, or a block replaced."""
    index = int(rng.integers(1, len(blocks)))
    block = blocks[index]
    choice = int(rng.integers(4))
    if choice == 0:
        changed = _random_block(rng, block.seconds, duty_limit)
    elif choice == 1 and block.kind != 'rest':
        level = float(np.clip(block.level + rng.normal(0, 0.1 * duty_limit), 0.05, duty_limit))
        amplitude = min(block.amplitude, level, duty_limit - level)
        changed = replace(block, level=level, amplitude=amplitude)
    elif choice == 2 and block.kind in ('sweep', 'square'):
        low, high = sorted(np.clip([block.start_hz, block.stop_hz] * np.exp(rng.normal(0, 0.3, 2)), 0.2, 5.0))
        changed = replace(block, start_hz=float(low), stop_hz=float(high))
    else:
        seconds = float(np.clip(block.seconds * math.exp(rng.normal(0, 0.3)), 0.5, duration - LEAD_REST))
        changed = replace(block, seconds=round(seconds / SWEEP_HOLD) * SWEEP_HOLD)
    result = blocks[:index] + (changed,) + blocks[index + 1:]
    total = sum(b.seconds for b in result)
    if total > duration:            # keep the budget: shrink the other blocks in proportion
        factor = (duration - LEAD_REST - changed.seconds) / max(total - LEAD_REST - changed.seconds, 1e-9)
        result = tuple(b if i in (0, index) else replace(b, seconds=max(0.5, b.seconds * factor))
                       for i, b in enumerate(result))
    return _fit_duration(result, duration)

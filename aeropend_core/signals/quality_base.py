"""The data-quality gate's vocabulary and tools: :class:`Finding`, :class:`DataQualityError`, :class:`QualityReport`,
the thresholds (rig physics, robust statistics) and the working state a check reads and repairs (see
:mod:`aeropend_core.signals.quality`).
"""
from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np

from aeropend_core.errors import AeropendError
from aeropend_core.io.samples import Recording


#: Finding severities, mildest first.
SEVERITIES = ('repaired', 'warning', 'refused')


#: The signals the gate checks (others, e.g. simulator truth, pass unchanged).
MEASURED = ('angle', 'armature_voltage', 'armature_current', 'duty')


#: Magnitude beyond which a value is absurd for every signal whatever its unit (rad, deg, V, mV, A, mA, s, ms).
ABSURD = 1e6


#: Largest plausible magnitudes for the rig, SI: a small DC motor (Ra ~ 1 ohm on a few volts) and its supply.
MAX_CURRENT = 20.0          # A


MAX_VOLTAGE = 30.0          # V


#: Rate of the angle [rad/s] (99th percentile over the record) above which the rod cannot be moving in radians:
#: the propeller's terminal spin is ~75 rad/s, a swinging rod stays below ~10 rad/s; degrees read 57 x faster.
MAX_ANGULAR_RATE = 40.0


#: Offset of the hanging angle [rad] beyond which the angle's zero is said to be wrong (20 deg).
REST_ANGLE_LIMIT = math.radians(20.0)


#: Largest believable one-sample change of the angle [rad] at any rig rate (245 rad/s at 490 Hz).
MAX_ANGLE_STEP = 0.5


#: Hampel filter: running-median width [samples] and threshold in robust standard deviations.
HAMPEL_WIDTH = 7


HAMPEL_SIGMAS = 10.0


#: Isolated defects (NaN, absurd values, outliers) are repaired up to this fraction of the samples...
MAX_REPAIRED_FRACTION = 0.005


#: ... in runs of at most this many samples; more is refused.
MAX_REPAIRED_RUN = 5


#: Shortest frozen span that counts as a stuck sensor [s] (when the input steps within it).
STUCK_SECONDS = 0.5


#: Time a sensor is given to respond to an input change before its silence counts [s].
STUCK_RESPONSE = 0.25


#: A frozen angle is read as a rod at rest (not a stuck sensor) when the reading within this time [s] before and
#: after the frozen span stays within ROD_HELD_COUNTS encoder counts of the frozen value (no jump at the thaw).
ROD_HELD_WINDOW = 0.02


ROD_HELD_COUNTS = 2


#: Peak signal-to-noise ratios [dB] below which a measured signal is refused / said to be very noisy.
MIN_PSNR_DB = 12.0


WARN_PSNR_DB = 17.0


#: Relative tolerance on the sample rate against the declared one.
RATE_TOLERANCE = 0.02


#: Stamps rounded or jittered by more than this fraction of the step cannot give the rate by themselves.
PRECISION_FRACTION = 0.01


@dataclass(frozen=True)
class Finding:
    """One defect of a recording.

    Attributes
    ----------
    code : str
        Stable snake_case name (see the module table), for programs.
    severity : str
        ``'repaired'`` (fixed, said), ``'warning'`` (kept as is, said) or ``'refused'`` (no number can be trusted).
    message : str
        One line: the problem, where in the record, what was done or what to do.
    where : tuple of float or None
        ``(t_start, t_stop)`` [s] of the affected span in the record's time, or None for the whole file.
    count : int
        How many samples (or columns) are affected.
    """

    code: str
    severity: str
    message: str
    where: tuple[float, float] | None = None
    count: int = 0

    def __post_init__(self) -> None:
        if self.severity not in SEVERITIES:
            raise ValueError(f'severity must be one of {SEVERITIES}, got {self.severity!r}')

    def to_dict(self) -> dict:
        """Plain JSON types: ``{code, severity, message, where: [t_start, t_stop] or null, count}``."""
        where = None if self.where is None else [float(self.where[0]), float(self.where[1])]
        return {'code': self.code, 'severity': self.severity, 'message': self.message, 'where': where,
                'count': int(self.count)}

    def line(self) -> str:
        """``severity (code): message`` for logs and reports."""
        return f'{self.severity} ({self.code}): {self.message}'


class DataQualityError(AeropendError):
    """A recording refused by the gate. ``finding`` is the refusal, ``findings`` everything found before it."""

    def __init__(self, finding: Finding, findings: Sequence[Finding] = ()) -> None:
        super().__init__(finding.message)
        self.finding = finding
        self.findings = tuple(findings)


@dataclass(frozen=True, eq=False)
class QualityReport:
    """The gate's answer: the repaired recording and every finding (the recording carries them too)."""

    recording: Recording
    findings: list[Finding] = field(default_factory=list)

    @property
    def clean(self) -> bool:
        return not self.findings

    def codes(self) -> list[str]:
        return [f.code for f in self.findings]

    def worst(self) -> str | None:
        """The most severe severity present, or None when clean."""
        present = [SEVERITIES.index(f.severity) for f in self.findings]
        return SEVERITIES[max(present)] if present else None


def findings_to_json(findings: Iterable[Finding]) -> list[dict]:
    """The ``"warnings": [...]`` list of every ``--json`` output."""
    return [f.to_dict() for f in findings]


def quality_lines(findings: Sequence[Finding]) -> str:
    """The "Data quality" section of a text report: ``Data quality: clean`` or one line per finding."""
    if not findings:
        return 'Data quality: clean (no repairs, no warnings)'
    lines = [f'Data quality: {len(findings)} finding(s); every number below comes from the data as repaired:']
    lines += [f'  {f.severity} ({f.code}): {f.message}' for f in findings]
    return '\n'.join(lines)


# ------------------------------------------------------------------------------------------------------ helpers
class _Gate:
    """State of one check: the arrays being repaired and the findings so far."""

    def __init__(self, time: np.ndarray, signals: dict[str, np.ndarray], source: str, context: str,
                 findings: Sequence[Finding]) -> None:
        self.time = np.array(time, dtype=float)
        self.signals = {k: np.array(v, dtype=float) for k, v in signals.items()}
        self.source = source
        self.context = context
        self.findings: list[Finding] = list(findings)

    # where / what to do -------------------------------------------------------------------------------------
    def t(self, index: int) -> float:
        index = int(min(max(index, 0), len(self.time) - 1))
        value = self.time[index]
        return float(value) if math.isfinite(value) else float('nan')

    def span(self, first: int, last: int) -> tuple[float, float]:
        return (self.t(first), self.t(last))

    def at(self, first: int, last: int | None = None) -> str:
        """'sample 12 (t = 0.0245 s)' or 'samples 12-40 (t = 0.0245-0.0816 s)'."""
        if last is None or last == first:
            return f'sample {first} (t = {self.t(first):.4f} s)'
        return f'samples {first}-{last} (t = {self.t(first):.4f}-{self.t(last):.4f} s)'

    @property
    def rate_hint(self) -> str:
        if self.context == 'window':
            return 'the identification assumes the rig\'s rate: fix the source (or its stamps)'
        return 'record every sample (or, if your rig really runs at that rate, give --sample-rate)'

    @property
    def cut_hint(self) -> str:
        if self.context == 'window':
            return 'the window is not analysed'
        return 'cut the record around it (identify --start/--stop) or fix the file'

    def add(self, code: str, severity: str, message: str, where: tuple[float, float] | None = None,
            count: int = 0) -> None:
        if where is not None and 't = ' not in message:        # every message says where
            message += f' (t = {where[0]:.4f}-{where[1]:.4f} s)'
        finding = Finding(code, severity, f'{self.source}: {message}', where, int(count))
        if severity == 'refused':
            raise DataQualityError(finding, self.findings)
        if finding not in self.findings:          # a recording checked twice keeps one copy of each finding
            self.findings.append(finding)


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """(first, last) index pairs of the runs of True in a boolean mask."""
    if not mask.any():
        return []
    padded = np.concatenate(([False], mask, [False])).astype(np.int8)
    edges = np.flatnonzero(np.diff(padded))
    return [(int(a), int(b) - 1) for a, b in zip(edges[::2], edges[1::2])]


def _interpolate(values: np.ndarray, bad: np.ndarray) -> np.ndarray:
    good = np.flatnonzero(~bad)
    out = values.copy()
    out[bad] = np.interp(np.flatnonzero(bad), good, values[good])
    return out


def _robust_sigma(values: np.ndarray) -> float:
    values = values[np.isfinite(values)]
    if values.size == 0:
        return 0.0
    return float(1.4826 * np.median(np.abs(values - np.median(values))))


def _quantum(values: np.ndarray, scale: float = 0.0) -> float:
    """Smallest difference between distinct values (the resolution of quantised data), or 0; differences below
    float rounding at magnitude `scale` (e.g. of stamps around t = 1e5 s) do not count."""
    distinct = np.unique(values[np.isfinite(values)])
    if distinct.size < 2:
        return 0.0
    gaps = np.diff(distinct)
    gaps = gaps[gaps > 64 * np.spacing(max(scale, float(np.max(np.abs(distinct)))))]
    return float(np.min(gaps)) if gaps.size else 0.0


def _running_median(values: np.ndarray, width: int = HAMPEL_WIDTH) -> np.ndarray:
    from scipy.ndimage import median_filter
    return median_filter(values, size=width, mode='nearest')


def _typical_rate(values: np.ndarray, sample_time: float) -> float:
    """99th percentile of the rate of change [unit/s] of a signal smoothed by a 0.1 s running median (noise
    barely reaches it)."""
    width = max(int(0.1 / sample_time) | 1, 3)
    if values.size < 3 * width:
        return 0.0
    smooth = _running_median(values, width)
    rate = np.abs(smooth[width:] - smooth[:-width]) / (width * sample_time)
    return float(np.percentile(rate[np.isfinite(rate)], 99))


def _robust_extent(values: np.ndarray) -> float:
    """Largest magnitude once the 0.1 % most extreme samples on each side are set aside."""
    finite = values[np.isfinite(values)]
    if finite.size == 0:
        return 0.0
    low, high = np.percentile(finite, [0.1, 99.9])
    return float(max(abs(low), abs(high)))

"""Where the model fails, in the state space: the missing acceleration binned by angle, direction of motion and thrust.

The free-run residual of the angle (measured minus simulated) says *that* the model misses something; it does not say
*where*: an error made in one band of angles is carried along the trajectory long after the rod has left it. The
acceleration the model misses is local. Along the record, with ``r`` the residual, the linearised pendulum gives

    g(t) = r'' + k cos(angle) r + c r'

(``k`` the gravity stiffness mgd/J [1/s^2], ``c`` the damping c/J [1/s], from the fitted model): the acceleration
[rad/s^2] that the model lacks at the state the rod is in. ``r'`` and ``r''`` come from a Savitzky-Golay filter
(scipy.signal.savgol_filter, cubic, ~60 ms) of the residual, so ``g`` is the missing acceleration averaged over that
window.

``g`` is binned by the measured (smoothed) angle in bands of ANGLE_BAND, by the direction of motion (rising, falling,
still below STILL_RATE) and by the model's thrust (terciles). A bin's mean has a cluster-robust standard error: the
samples of one visit to a bin are one cluster (a visit's samples share the same slow error), so the ± counts visits,
not samples. The map is *localised* along one axis when its region -- the strongest bin (beyond Z_SIGNIFICANT) and its
neighbours of the same sign beyond Z_EXTEND (contiguous along angle and thrust) -- holds at least LOCAL_SHARE of the
axis' mean-square missing acceleration while covering at most MAX_COVER of its samples; else the missing acceleration
is spread over that axis, or there is none to place.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

#: Width of an angle band [rad] (5 degrees).
ANGLE_BAND = math.radians(5.0)
#: Below this |rate| [rad/s] the rod counts as still.
STILL_RATE = 0.05
#: Savitzky-Golay window for the residual's derivatives [s].
DERIVATIVE_WINDOW = 0.06
#: A bin's mean counts as nonzero beyond this many (cluster-robust) standard errors.
Z_SIGNIFICANT = 4.0
#: A neighbour of the strongest bin with the same sign beyond this many standard errors belongs to its region.
Z_EXTEND = 3.0
#: ... and the axis is localised when the significant bins hold this share of its mean-square missing acceleration ...
LOCAL_SHARE = 0.7
#: ... while covering at most this share of the axis' samples.
MAX_COVER = 0.6
#: A bin needs this share of the mapped samples (at least MIN_SAMPLES) and MIN_VISITS visits to be judged: a band
#: visited briefly at the end of a swing holds a few hundred samples of the largest accelerations, too few to judge.
MIN_SHARE = 0.01
MIN_SAMPLES = 200
MIN_VISITS = 6

DIRECTIONS = ('rising', 'falling', 'still')
THRUSTS = ('low', 'middle', 'high')


@dataclass(frozen=True)
class AxisBin:
    """One bin of one axis of the map (the others pooled)."""

    label: str
    low: float              #: lower edge [rad for angle, rad/s^2 for thrust; nan for direction]
    high: float
    samples: int
    visits: int
    mean: float             #: mean missing acceleration [rad/s^2]
    standard_error: float   #: cluster-robust 1σ of the mean [rad/s^2]

    @property
    def z(self) -> float:
        return self.mean / self.standard_error if self.standard_error > 0 else 0.0

    def to_dict(self) -> dict:
        return {'label': self.label, 'low': _finite(self.low), 'high': _finite(self.high), 'samples': self.samples,
                'visits': self.visits, 'mean_missing_acceleration': _finite(self.mean),
                'standard_error': _finite(self.standard_error), 'z': _finite(self.z)}


@dataclass(frozen=True)
class AxisVerdict:
    """Whether the missing acceleration is confined along one axis, and where."""

    axis: str                        #: 'angle', 'angle_opposing_motion', 'direction' or 'thrust'
    bins: tuple[AxisBin, ...]
    localised: bool
    region: tuple[str, ...] = ()     #: labels of the bins the missing acceleration sits in
    low: float = math.nan            #: the region's edges (angle [rad], thrust [rad/s^2])
    high: float = math.nan
    share: float = math.nan          #: share of the axis' mean-square missing acceleration in the region
    cover: float = math.nan          #: share of the axis' samples in the region

    def to_dict(self) -> dict:
        return {'axis': self.axis, 'localised': self.localised, 'region': list(self.region), 'low': _finite(self.low),
                'high': _finite(self.high), 'share': _finite(self.share), 'cover': _finite(self.cover),
                'bins': [b.to_dict() for b in self.bins]}


@dataclass(frozen=True)
class StateMap:
    """The missing acceleration over the state space of one model on one record (module docstring)."""

    model_effects: tuple[str, ...]
    axes: tuple[AxisVerdict, ...] = ()
    rms_missing_acceleration: float = math.nan     #: RMS of the binned means, weighted by samples [rad/s^2]
    significant: bool = False                      #: some bin's mean is beyond Z_SIGNIFICANT
    cells: tuple[dict, ...] = field(default=())     #: angle band x direction (for the report's map)
    note: str = ''

    def axis(self, name: str) -> AxisVerdict | None:
        return next((a for a in self.axes if a.axis == name), None)

    @property
    def localised(self) -> tuple[AxisVerdict, ...]:
        return tuple(a for a in self.axes if a.localised)

    def to_dict(self) -> dict:
        return {'model_effects': list(self.model_effects), 'unit': 'rad/s^2',
                'quantity': 'missing angular acceleration (local, from the free-run residual)',
                'rms_missing_acceleration': _finite(self.rms_missing_acceleration), 'significant': self.significant,
                'axes': [a.to_dict() for a in self.axes], 'cells': list(self.cells), 'note': self.note}


def _finite(value: float) -> float | None:
    return float(value) if value is not None and math.isfinite(value) else None


def _filled(simulated: np.ndarray, longest: int = 4) -> np.ndarray:
    """`simulated` with runs of at most `longest` missing samples between finite ones linearly interpolated (the
    training segments are simulated on the fit's integration grid, every other sample)."""
    simulated = np.array(simulated, float)
    missing = ~np.isfinite(simulated)
    if not missing.any() or missing.all():
        return simulated
    index = np.arange(simulated.size)
    known = index[~missing]
    filled = np.interp(index, known, simulated[~missing])
    # distance to the previous and next finite sample: only short holes inside finite stretches are filled
    previous = known[np.clip(np.searchsorted(known, index) - 1, 0, known.size - 1)]
    following = known[np.clip(np.searchsorted(known, index), 0, known.size - 1)]
    short = missing & (following > index) & (previous < index) & (following - previous <= longest)
    simulated[short] = filled[short]
    return simulated


def missing_acceleration(prep, comparison) -> tuple[np.ndarray, np.ndarray]:
    """(g [rad/s^2] per sample, mask of the samples where it is defined): module docstring's formula on each stretch
    of consecutive samples with a finite simulation (the training segments and the held-out part)."""
    from aeropend_core.signals.filters import savgol_filter
    simulated = _filled(comparison.evaluation.simulated)
    residual = prep.angle - simulated
    parameters = comparison.parameters
    stiffness = float(parameters.get('gravity_stiffness', 0.0))
    damping = float(parameters.get('damping', 0.0))
    step = prep.sample_time
    window = max(7, int(round(DERIVATIVE_WINDOW / step)) | 1)
    usable = np.isfinite(residual)
    if prep.gaps is not None:
        usable &= np.asarray(prep.gaps.valid, bool)
    g = np.full(residual.shape, np.nan)
    edges = np.flatnonzero(np.diff(np.concatenate(([0], usable.view(np.int8), [0]))))
    for start, stop in zip(edges[::2], edges[1::2]):
        if stop - start < 3 * window:
            continue
        piece = residual[start:stop]
        rate = savgol_filter(piece, window, 3, deriv=1, delta=step)
        acceleration = savgol_filter(piece, window, 3, deriv=2, delta=step)
        g[start:stop] = acceleration + stiffness * np.cos(prep.smoothed_angle[start:stop]) * piece + damping * rate
        g[start:start + window // 2] = np.nan          # the filter's edges see one side only
        g[stop - window // 2:stop] = np.nan
    return g, np.isfinite(g)


def _clustered_mean(values: np.ndarray, labels: np.ndarray, inside: np.ndarray) -> tuple[float, float, int, int]:
    """(mean, cluster-robust 1σ, samples, visits) of `values` where `inside`; a visit is a run of consecutive samples
    inside (``labels`` number the runs of the whole record)."""
    n = int(np.count_nonzero(inside))
    if n == 0:
        return math.nan, math.nan, 0, 0
    x, runs = values[inside], labels[inside]
    mean = float(x.mean())
    _, index = np.unique(runs, return_inverse=True)
    sums = np.bincount(index, weights=x - mean)
    visits = sums.size
    if visits < 2:
        return mean, math.nan, n, visits
    variance = float(np.sum(sums ** 2)) / n ** 2 * visits / (visits - 1)
    return mean, math.sqrt(variance), n, visits


def _visits_mean(values: np.ndarray, inside: np.ndarray) -> tuple[float, float, int, int]:
    """:func:`_clustered_mean` of `values` where `inside`, each run of consecutive samples inside one visit."""
    runs = np.cumsum(np.concatenate(([True], np.diff(inside.view(np.int8)) != 0)))
    return _clustered_mean(values, runs, inside)


def _bins(g, usable, classes: np.ndarray, labels: list[str], edges: list[tuple[float, float]]) -> list[AxisBin]:
    least = max(MIN_SAMPLES, int(MIN_SHARE * np.count_nonzero(usable)))
    out = []
    for value, (label, (low, high)) in enumerate(zip(labels, edges)):
        mean, sigma, n, visits = _visits_mean(g, usable & (classes == value))
        if n >= least and visits >= MIN_VISITS and math.isfinite(sigma):
            out.append(AxisBin(label, low, high, n, visits, mean, sigma))
    return out


def _judge(axis: str, bins: list[AxisBin], contiguous: bool) -> AxisVerdict:
    if not bins:
        return AxisVerdict(axis, (), False)
    energy = np.array([b.samples * b.mean ** 2 for b in bins])
    samples = np.array([b.samples for b in bins], float)
    significant = np.array([abs(b.z) >= Z_SIGNIFICANT for b in bins])
    if not significant.any() or energy.sum() <= 0:
        return AxisVerdict(axis, tuple(bins), False)
    # the region grows from the strongest bin over its neighbours of the same sign beyond Z_EXTEND: a model that
    # absorbs part of a local effect (gravity, damping, thrust gain refitted) leaves opposite-signed bins elsewhere,
    # which are its compensation, not the effect's place
    z = np.array([b.z for b in bins])
    peak = int(np.argmax(np.abs(z)))
    same = (np.sign(z) == np.sign(z[peak])) & (np.abs(z) >= Z_EXTEND)
    region = np.zeros(len(bins), bool)
    region[peak] = True
    if contiguous:
        for step in (-1, 1):
            index = peak + step
            while 0 <= index < len(bins) and same[index]:
                region[index] = True
                index += step
    else:
        region |= same & significant
    share = float(energy[region].sum() / energy.sum())
    cover = float(samples[region].sum() / samples.sum())
    localised = bool(share >= LOCAL_SHARE and cover <= MAX_COVER)
    if axis == 'direction' and localised:
        # both directions of motion clearly nonzero (of opposite signs: a friction or drag) is no one-way effect
        moving = [b for b in bins if b.label in DIRECTIONS[:2] and b.label not in region]
        localised = not any(abs(b.z) >= Z_EXTEND for b in moving)
    chosen = [b for b, inside in zip(bins, region) if inside]
    return AxisVerdict(axis, tuple(bins), localised, tuple(b.label for b in chosen), min(b.low for b in chosen),
                       max(b.high for b in chosen), share, cover)


def state_map(prep, comparison, effects: tuple[str, ...] = ()) -> StateMap:
    """The missing acceleration of `comparison` on `prep`, binned and judged for localisation (module docstring).

    Parameters
    ----------
    prep : PreparedRecord [-]
    comparison : Comparison [-]
        A fitted model with its simulation over the whole record.
    effects : tuple of str [-]
        The model's effects (for the label).

    Returns
    -------
    StateMap
    """
    g, usable = missing_acceleration(prep, comparison)
    if np.count_nonzero(usable) < 4 * MIN_SAMPLES:
        return StateMap(tuple(effects), note='too few samples with a simulated angle to map the missing acceleration')
    # the state is the model's (noise-free) trajectory: classifying by the measured angle's own noise would select
    # samples by the residual's noise and bias the bins (a clean record showed +-1 rad/s^2 by direction of motion)
    simulated = _filled(comparison.evaluation.simulated)
    offset = comparison.parameters.get(comparison.fit.structure.offset_parameter or '', 0.0)
    angle = np.nan_to_num(simulated - offset)
    rate = np.gradient(angle, prep.sample_time)
    values = comparison.parameters
    e = prep.voltage - values.get('armature_resistance', 0.0) * prep.current
    thrust = values.get('thrust_gain', 1.0) * e * np.abs(e)
    # angle bands of ANGLE_BAND aligned on multiples of it
    band = np.floor(angle / ANGLE_BAND).astype(int)
    present = np.unique(band[usable])
    angle_class = np.searchsorted(present, band).clip(0, len(present) - 1)
    angle_class[~np.isin(band, present)] = -1
    angle_edges = [(b * ANGLE_BAND, (b + 1) * ANGLE_BAND) for b in present]
    angle_labels = [f'{math.degrees(lo):.0f} to {math.degrees(hi):.0f} deg' for lo, hi in angle_edges]
    direction = np.where(rate > STILL_RATE, 0, np.where(rate < -STILL_RATE, 1, 2))
    moving = usable & (direction < 2)
    # the part that opposes the motion (positive: a drag or friction the model lacks), where the rod moves
    opposing = np.where(moving, -g * np.sign(rate), np.nan)
    cuts = np.quantile(thrust[usable], [1 / 3, 2 / 3])
    thrust_class = np.searchsorted(cuts, thrust)
    low, high = float(np.min(thrust[usable])), float(np.max(thrust[usable]))
    thrust_edges = [(low, cuts[0]), (cuts[0], cuts[1]), (cuts[1], high)]
    axes = (_judge('angle', _bins(g, usable, angle_class, angle_labels, angle_edges), contiguous=True),
            _judge('angle_opposing_motion', _bins(opposing, moving, angle_class, angle_labels, angle_edges),
                   contiguous=True),
            _judge('direction', _bins(g, usable, direction, list(DIRECTIONS), [(math.nan, math.nan)] * 3), False),
            _judge('thrust', _bins(g, usable, thrust_class, list(THRUSTS), thrust_edges), contiguous=True))
    means = [(b.samples, b.mean) for b in axes[0].bins]
    total = sum(n for n, _ in means)
    rms = math.sqrt(sum(n * m ** 2 for n, m in means) / total) if total else math.nan
    significant = any(abs(b.z) >= Z_SIGNIFICANT for a in axes for b in a.bins)
    cells = []
    for index, (label, (lo, hi)) in enumerate(zip(angle_labels, angle_edges)):
        for way, name in enumerate(DIRECTIONS[:2]):
            mean, sigma, n, visits = _visits_mean(g, usable & (angle_class == index) & (direction == way))
            if n >= MIN_SAMPLES and visits >= MIN_VISITS and math.isfinite(sigma):
                cells.append({'angle_low': lo, 'angle_high': hi, 'direction': name, 'samples': n,
                              'mean_missing_acceleration': mean, 'standard_error': sigma})
    return StateMap(tuple(effects), axes, rms, significant, tuple(cells))


__all__ = ['StateMap', 'AxisVerdict', 'AxisBin', 'state_map', 'missing_acceleration', 'ANGLE_BAND']

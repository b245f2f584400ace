"""A live plot of the online identification: each parameter over the windows with its ±1σ band (matplotlib).

Used by ``aeropend monitor`` when it has a display (or ``--plot-file``): one panel per parameter (value line, ±1σ
band, the estimator and the SI unit in the title, a drift named in red in the title, windows whose data were
repaired or flagged marked with a red ×), and the held-out fit % below, against acquisition time (as ``aeropend
run`` prints it). Each axis is scaled to the recent windows robustly (:func:`robust_limits`: median ± k·MAD), so one
bad window does not squash the others into a line: a value beyond the axis is drawn at its edge as a red triangle
pointing the way it went. ROS-free: it draws what it is given.
"""
from __future__ import annotations

import math
import os
import sys
from dataclasses import dataclass, field

#: Parameters drawn first, in this order (others follow as they appear: the effects' parameters).
FIRST = ('gravity_stiffness', 'damping', 'thrust_gain', 'armature_resistance')
#: Half-width of the axis in robust standard deviations (1.4826 MAD) around the median of the recent windows [-].
LIMIT_MADS = 6.0
#: Windows the axis limits are taken from (the most recent) [-].
LIMIT_WINDOWS = 30
#: A window's ±1σ band is kept on the axis up to this many times the recent windows' median σ; a wider one (a damaged
#: window's) is cut at the edge and said in the title [-].
BAND_WIDEST = 3.0


def robust_limits(values, k: float = LIMIT_MADS, recent: int = LIMIT_WINDOWS) -> tuple[float, float] | None:
    """Axis limits from the recent values: median ± `k` robust standard deviations (1.4826·MAD), never wider than
    the values themselves, plus a 10 % margin. One wild window (a damaged one) does not stretch the axis.

    Parameters
    ----------
    values : array_like, shape (n,)
        The quantity over the windows, oldest first (in its unit; NaN ignored).
    k : float
        Half-width in robust standard deviations [-].
    recent : int
        How many of the last values set the limits [-].

    Returns
    -------
    tuple of float or None
        ``(low, high)`` in the values' unit; None when no value is finite.
    """
    import numpy as np
    v = np.asarray(values, dtype=float)[-recent:]
    v = v[np.isfinite(v)]
    if v.size == 0:
        return None
    median = float(np.median(v))
    spread = 1.4826 * float(np.median(np.abs(v - median)))
    low, high = max(float(v.min()), median - k * spread), min(float(v.max()), median + k * spread)
    if high - low <= 0.0:
        pad = max(abs(median) * 0.05, 1e-12)
        return median - pad, median + pad
    margin = 0.1 * (high - low)
    return low - margin, high + margin


def has_display() -> bool:
    """True when matplotlib can open a window here: a display (X11 or Wayland; always on macOS and Windows) and an
    interactive backend (``MPLBACKEND=Agg`` says no)."""
    if sys.platform.startswith('linux') and not (os.environ.get('DISPLAY') or os.environ.get('WAYLAND_DISPLAY')):
        return False
    try:
        import matplotlib
    except ImportError:
        return False
    backend = (os.environ.get('MPLBACKEND') or matplotlib.get_backend() or '').lower()
    return backend not in ('agg', 'pdf', 'ps', 'svg', 'cairo', 'template') and 'inline' not in backend


@dataclass
class WindowPoint:
    """One window's parameters as drawn.

    Attributes
    ----------
    time : float
        End of the window, acquisition time since the stream's first sample [s] (the time ``aeropend run``
        prints).
    values : dict
        ``{name: (value, sigma)}`` in SI units (sigma NaN: unknown, no band).
    fit_percent : float
        Held-out fit [%].
    flagged : bool
        The window's data were repaired, filled or warned about.
    """

    time: float
    values: dict[str, tuple[float, float]]
    fit_percent: float = float('nan')
    flagged: bool = False


@dataclass
class LivePlot:
    """The figure, redrawn from the history of windows (the last `keep` of them).

    Parameters
    ----------
    interactive : bool
        Open a window (pyplot, interactive mode) or draw off-screen (Agg; :meth:`save`).
    keep : int
        Windows kept for drawing [-].
    """

    interactive: bool = False
    keep: int = 500
    points: list[WindowPoint] = field(default_factory=list)
    units: dict[str, str] = field(default_factory=dict)
    estimators: dict[str, str] = field(default_factory=dict)
    drift: dict[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        import matplotlib
        if self.interactive:
            import matplotlib.pyplot as plt
            plt.ion()
            self.figure = plt.figure('aeropend monitor', figsize=(10, 8))
        else:
            from matplotlib.figure import Figure
            self.figure = Figure(figsize=(10, 8))
        self._matplotlib = matplotlib

    def add(self, point: WindowPoint) -> None:
        """Add one window [-] (the oldest is dropped beyond `keep`)."""
        self.points.append(point)
        del self.points[:-self.keep]

    def names(self) -> list[str]:
        """Parameters to draw: :data:`FIRST` that appear, then the others in order of appearance (not the derived
        ones, e.g. thrust_coefficient: no diagnosis prints them)."""
        from aeropend_core.model.names import DERIVED_PARAMETERS
        seen: list[str] = []
        for point in self.points:
            seen += [name for name in point.values if name not in seen and name not in DERIVED_PARAMETERS]
        return [name for name in FIRST if name in seen] + [name for name in seen if name not in FIRST]

    def draw(self) -> None:
        """Redraw the whole figure from the history."""
        import numpy as np
        figure = self.figure
        figure.clf()
        names = self.names()
        rows = len(names) + 1
        if not self.interactive:            # a saved frame grows with the panels; a window keeps the user's size
            figure.set_size_inches(10, max(6.0, 1.6 * rows))
        times = np.array([p.time for p in self.points])
        for row, name in enumerate(names):
            axes = figure.add_subplot(rows, 1, row + 1)
            value = np.array([p.values.get(name, (math.nan, math.nan))[0] for p in self.points], dtype=float)
            sigma = np.array([p.values.get(name, (math.nan, math.nan))[1] for p in self.points], dtype=float)
            axes.plot(times, value, '-o', color='#1f63b4', markersize=2, linewidth=1.2, label='value')
            axes.fill_between(times, value - sigma, value + sigma, color='#7fa8d9', alpha=0.4, linewidth=0,
                              label='±1σ')
            flagged = np.array([p.flagged for p in self.points], dtype=bool)
            if flagged.any():
                axes.plot(times[flagged], value[flagged], 'x', color='#d7301f', label='data repaired/flagged')
            cut = self._robust_axis(axes, times, value, sigma, self.units.get(name, ''))
            unit = self.units.get(name, '')
            estimator = self.estimators.get(name, '')
            title = f'{name} [{unit}]' + (f' — {estimator}' if estimator else '')
            if not np.isfinite(sigma).any():
                title += ' (σ unknown: no band)'
            elif cut:
                title += f' (±1σ band wider than the axis in {cut} window(s): cut at its edge)'
            drift = self.drift.get(name, '')
            axes.set_title(title + (f'   {drift}' if drift else ''), fontsize=8, loc='left',
                           color='#d7301f' if 'DRIFT' in drift else 'black')
            axes.tick_params(labelsize=7)
            if row == 0 or any(line.get_label().startswith('off scale') for line in axes.get_lines()):
                axes.legend(fontsize=7, loc='upper right')
        axes = figure.add_subplot(rows, 1, rows)
        fit = np.array([p.fit_percent for p in self.points], dtype=float)
        axes.plot(times, fit, '-o', color='#1a9641', markersize=2, label='held-out fit')
        self._robust_axis(axes, times, fit, unit='%')
        if any(line.get_label().startswith('off scale') for line in axes.get_lines()):
            axes.legend(fontsize=7, loc='lower right')
        axes.set_title('held-out fit [%] (MATLAB compare NRMSE)', fontsize=8, loc='left')
        axes.set_xlabel('window end [s], acquisition time since the run began (as aeropend run prints it)',
                        fontsize=8)
        axes.tick_params(labelsize=7)
        figure.tight_layout()
        if self.interactive:
            import matplotlib.pyplot as plt
            figure.canvas.draw_idle()
            plt.pause(0.001)

    @staticmethod
    def _robust_axis(axes, times, value, sigma=None, unit: str = '') -> int:
        """Limit the y axis to :func:`robust_limits` of `value` and its ±1σ band (`sigma`, same unit); a value beyond
        it is drawn at its edge as a red ▲/▼ labelled with the value and `unit`. Returns how many windows' bands
        the limits cut (a band wider than the recent windows' spread, e.g. a σ of a damaged window)."""
        import numpy as np
        sigma = np.full_like(value, np.nan) if sigma is None else np.asarray(sigma, dtype=float)
        limits = robust_limits(value)
        if limits is None:
            return 0
        low, high = limits
        # the bands of the windows on the axis, unless a band is far wider than the recent windows' usual one; a value
        # within BAND_WIDEST usual sigmas of the median is on the axis too (few windows make a narrow robust range)
        recent = sigma[-LIMIT_WINDOWS:][np.isfinite(sigma[-LIMIT_WINDOWS:])]
        usual = float(np.median(recent)) if recent.size else 0.0
        middle = float(np.nanmedian(value[-LIMIT_WINDOWS:]))
        inside = np.isfinite(value) & (((value >= low) & (value <= high))
                                       | (np.abs(value - middle) <= BAND_WIDEST * usual))
        banded = inside & np.isfinite(sigma) & (sigma <= BAND_WIDEST * usual)
        cut = int(np.sum(inside & np.isfinite(sigma) & ~banded))
        if banded.any():
            low = min(low, float(np.min(value[banded] - sigma[banded])))
            high = max(high, float(np.max(value[banded] + sigma[banded])))
            margin = 0.05 * (high - low)
            low, high = low - margin, high + margin
        axes.set_ylim(low, high)
        above, below = value > high, value < low
        for where, edge, marker, offset in ((above, high, '^', -9), (below, low, 'v', 4)):
            if not where.any():
                continue
            axes.plot(times[where], np.full(int(where.sum()), edge), marker, color='#d7301f', markersize=5,
                      clip_on=False, label='off scale (beyond the axis; its value beside it)')
            for t, v in zip(times[where][-3:], value[where][-3:]):      # the latest three, not a pile of text
                axes.annotate(f'{v:.4g} {unit}'.strip(), (t, edge), textcoords='offset points', xytext=(4, offset),
                              fontsize=6.5, color='#d7301f', annotation_clip=False)
        return cut

    def save(self, path: str) -> None:
        """Write the current figure to `path` (PNG, SVG or PDF by its suffix) [-], replacing it whole."""
        from aeropend_core.io.atomic import atomic_write
        form = os.path.splitext(path)[1].lstrip('.') or None
        atomic_write(path, lambda handle: self.figure.savefig(handle, dpi=80, format=form), binary=True)

    def alive(self) -> bool:
        """False once the user closed the window (interactive only)."""
        if not self.interactive:
            return True
        import matplotlib.pyplot as plt
        return plt.fignum_exists(self.figure.number)


__all__ = ['LivePlot', 'WindowPoint', 'has_display', 'robust_limits']

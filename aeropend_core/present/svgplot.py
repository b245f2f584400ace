"""Inline SVG plots for the diagnosis report, written directly from NumPy arrays.

The browser lays out the text and the ticks; Python only maps the (already decimated,
:func:`aeropend_core.present.formatting.envelope`) samples to pixel coordinates and writes them as SVG paths. This
replaced matplotlib PNGs, whose tick and text layout cost about 0.25 s per figure (eight figures: 2-3 s of CPU for
a 60 s record; ``bench/bench_report.py``). A figure here is a few milliseconds.

Usage: ``figure = Figure(height=300)``; ``axes = figure.grid(...)`` or ``figure.add_axes(...)``; draw with
:meth:`Axes.line`, :meth:`Axes.points`, :meth:`Axes.fill`, :meth:`Axes.span`, :meth:`Axes.bars` and
:meth:`Axes.text`; ``figure.html(alt)`` returns a ``<figure>`` holding an HTML legend and the ``<svg>``. Coordinates
are pixels of the SVG's view box (:data:`WIDTH` wide, scaled to the page's width by the browser).
"""
from __future__ import annotations

import html
import math
from collections.abc import Sequence

import numpy as np

#: Width of every figure's view box [px]: the report's content width, so that one unit is one screen pixel there.
WIDTH = 1130

#: Font size of tick labels and annotations [px].
TICK_FONT = 11.5

#: Font size of axis labels and titles [px].
LABEL_FONT = 12.5

#: Length of a dash in dashed and dotted lines [px].
DASHES = {'-': None, '--': '7 4', ':': '1.5 3', '-.': '7 3 1.5 3'}


def _esc(value: object) -> str:
    return html.escape(str(value), quote=True)


def nice_ticks(low: float, high: float, count: int = 6) -> tuple[np.ndarray, float]:
    """Tick positions at 1, 2 or 5 times a power of ten covering [low, high] with about `count` ticks.

    Parameters
    ----------
    low, high : float [unit of the axis]
        The axis limits.
    count : int [-]
        Wanted number of ticks.

    Returns
    -------
    tuple
        (ticks inside the limits [unit of the axis], step between ticks [unit of the axis]).
    """
    span = high - low
    if not (np.isfinite(span) and span > 0):
        return np.array([low]), 1.0
    raw = span / max(count, 1)
    power = 10.0 ** math.floor(math.log10(raw))
    step = next(m * power for m in (1, 2, 2.5, 5, 10) if m * power >= raw)
    first = math.ceil(low / step - 1e-9) * step
    ticks = np.arange(first, high + step * 1e-9, step)
    return ticks, step


def tick_labels(ticks: np.ndarray, step: float) -> list[str]:
    """Labels for `ticks` with as many decimals as their `step` needs (minus as U+2212)."""
    decimals = max(0, -math.floor(math.log10(step) + 1e-9)) if step > 0 else 0
    if step > 0 and round(step / 10.0 ** -decimals, 6) % 1:          # 2.5, 0.25: one more decimal
        decimals += 1
    labels = []
    for value in ticks:
        text = f'{0.0 if abs(value) < step * 1e-6 else value:.{decimals}f}'
        labels.append(text.replace('-', '\u2212'))
    return labels


#: Coordinates are clamped to this many pixels from the view box (far outside, hidden by the clipping; keeps the
#: integer arithmetic of :func:`_relative` exact).
FAR = 1e6


def _tenths(values: np.ndarray) -> list[str]:
    """Integers in tenths of a pixel as the shortest exact decimal text (15 -> '1.5', -3 -> '-.3', 20 -> '2')."""
    out = []
    for k in np.asarray(values).tolist():
        whole, tenth = divmod(abs(k), 10)
        text = (str(whole) if whole else '') + (f'.{tenth}' if tenth else '') or '0'
        out.append('-' + text if k < 0 else text)
    return out


def _pixels_in_tenths(values: np.ndarray) -> np.ndarray:
    """Pixel coordinates [px] as integers in tenths of a pixel (clamped to +-:data:`FAR`)."""
    return np.rint(np.clip(values, -FAR, FAR) * 10).astype(np.int64)


def _runs(px: np.ndarray, py: np.ndarray) -> list[np.ndarray]:
    """Index runs of the points with finite coordinates (a non-finite point ends a run)."""
    index = np.flatnonzero(np.isfinite(px) & np.isfinite(py))
    if index.size == 0:
        return []
    return np.split(index, np.flatnonzero(np.diff(index) > 1) + 1)


def _relative(px: np.ndarray, py: np.ndarray) -> str:
    """Path data through the points [px]: 'M x y l dx dy ...' with coordinates rounded to a tenth of a pixel (the
    steps are taken between rounded points, so no rounding error accumulates); a non-finite point starts a new
    piece. About 8 characters a point, against 11 for absolute coordinates."""
    pieces = []
    for run in _runs(px, py):
        x, y = _pixels_in_tenths(px[run]), _pixels_in_tenths(py[run])
        steps = np.column_stack([np.diff(x), np.diff(y)]).ravel()
        first = ' '.join(_tenths(np.array([x[0], y[0]])))
        pieces.append(f'M{first}' + (('l' + ' '.join(_tenths(steps))) if steps.size else ''))
    return ''.join(pieces).replace(' -', '-')


def _coordinates(px: np.ndarray, py: np.ndarray) -> list[str]:
    """'x y' pairs [px, one decimal] of the finite points, one string per run between non-finite ones."""
    out = []
    for run in _runs(px, py):
        pairs = np.column_stack([px[run], py[run]]).ravel()
        out.append(('%.1f %.1f ' * run.size % tuple(pairs)).rstrip())
    return out


class Axes:
    """One plotting area: a pixel box, the data drawn in it and its limits, ticks and labels.

    Parameters
    ----------
    left, top, width, height : float [px]
        The plotting area inside the figure's view box.
    """

    def __init__(self, left: float, top: float, width: float, height: float):
        self.box = (left, top, width, height)
        self._items: list[tuple] = []
        self._x: list[float] = []
        self._y: list[float] = []
        self.xlim: tuple[float, float] | None = None
        self.ylim: tuple[float, float] | None = None
        self.xlabel = self.ylabel = self.title = ''
        self.yticks: tuple[Sequence[float], Sequence[str]] | None = None
        self.show_xticks = True
        self.grid = 'xy'
        self.background: str | None = None
        self.legend: list[tuple[str, str, dict]] = []
        self.shared: Axes | None = None
        self._above: list[Axes] = []
        #: The x axis can be zoomed and panned in the browser (:data:`ZOOM_SCRIPT`): the data are drawn in a group
        #: the script scales along x, the x tick labels are rewritten for the view.
        self.zoom_x = False

    # -- data -----------------------------------------------------------------------------------------------------

    def _extent(self, x, y) -> None:
        for values, store in ((x, self._x), (y, self._y)):
            if values is None:
                continue
            values = np.asarray(values, dtype=float)
            finite = values[np.isfinite(values)]
            if finite.size:
                store += [float(finite.min()), float(finite.max())]

    def _key(self, label: str | None, kind: str, colour: str, **style) -> None:
        if label and all(label != entry[0] for entry in self.legend):
            self.legend.append((label, kind, dict(colour=colour, **style)))

    def line(self, x, y, colour: str, width: float = 1.2, style: str = '-', opacity: float = 1.0,
             label: str | None = None, scale: bool = True) -> None:
        """A line through (x [data], y [data]); NaN separates pieces. ``scale=False``: not counted in the limits."""
        x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
        if scale:
            self._extent(x, y)
        self._items.append(('line', x, y, colour, width, style, opacity))
        self._key(label, 'line', colour, width=width, style=style, opacity=opacity)

    def points(self, x, y, colour: str, size: float = 3.0, opacity: float = 1.0, label: str | None = None) -> None:
        """Round dots of diameter `size` [px] at (x, y) [data]."""
        x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
        self._extent(x, y)
        self._items.append(('points', x, y, colour, size, opacity))
        self._key(label, 'points', colour, size=size, opacity=opacity)

    def fill(self, x, low, high, colour: str, opacity: float = 0.25, label: str | None = None) -> None:
        """The area between `low` and `high` over `x` [data]; NaN separates pieces."""
        x, low, high = (np.asarray(v, dtype=float) for v in (x, low, high))
        self._extent(x, low)
        self._extent(None, high)
        self._items.append(('fill', x, low, high, colour, opacity))
        self._key(label, 'fill', colour, opacity=opacity)

    def span(self, x0=None, x1=None, y0=None, y1=None, colour: str = '#dddddd', opacity: float = 1.0,
             label: str | None = None) -> None:
        """A shaded band: between x0 and x1 [data] over the full height, or between y0 and y1 over the full width.
        Not counted in the limits."""
        self._items.append(('span', x0, x1, y0, y1, colour, opacity))
        self._key(label, 'fill', colour, opacity=opacity)

    def rule(self, x=None, y=None, colour: str = '#000000', width: float = 0.8, style: str = '-',
             label: str | None = None) -> None:
        """A vertical line at x or a horizontal line at y [data] across the axes (not counted in the limits)."""
        self._items.append(('rule', x, y, colour, width, style))
        self._key(label, 'line', colour, width=width, style=style, opacity=1.0)

    def bars(self, positions, starts, ends, height: float, colour: str, opacity: float = 1.0,
             label: str | None = None) -> None:
        """Horizontal bars from `starts` to `ends` [data x] centred on `positions` [data y], `height` [data y]."""
        positions, starts, ends = (np.asarray(v, dtype=float) for v in (positions, starts, ends))
        self._extent(np.concatenate([starts, ends]), np.concatenate([positions - height / 2,
                                                                     positions + height / 2]))
        self._items.append(('bars', positions, starts, ends, height, colour, opacity))
        self._key(label, 'fill', colour, opacity=opacity)

    def marker(self, x: float, y: float, shape: str, colour: str, size: float = 9.0) -> None:
        """A triangle pointing left ('<') or right ('>') with its tip at (x, y) [data], `size` [px]."""
        self._items.append(('marker', x, y, shape, colour, size))

    def text(self, x: float, y: float, text: str, colour: str = '#333333', size: float = TICK_FONT,
             anchor: str = 'start', dx: float = 0.0, dy: float = 0.0, bold: bool = False,
             y_fraction: bool = False) -> None:
        """A label at (x [data], y [data, or a fraction of the height from the bottom with ``y_fraction``]) moved
        by (dx, dy) [px]; anchor 'start', 'middle' or 'end'."""
        self._items.append(('text', x, y, text, colour, size, anchor, dx, dy, bold, y_fraction))

    # -- limits and mapping -----------------------------------------------------------------------------------------

    def _limits(self, values: list[float], given, margin: float) -> tuple[float, float]:
        if given is not None:
            low, high = given
        elif values:
            low, high = min(values), max(values)
            pad = (high - low) * margin
            low, high = low - pad, high + pad
        else:
            low, high = 0.0, 1.0
        if not high > low:
            low, high = low - 0.5 * max(abs(low), 1.0), high + 0.5 * max(abs(high), 1.0)
        return float(low), float(high)

    def limits(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """((x low, x high), (y low, y high)) [data] as drawn."""
        root = self.shared or self
        xs = root._x + [value for other in root._above for value in other._x]
        xlim = self.xlim if self.xlim is not None else root.xlim
        return self._limits(xs, xlim, 0.0), self._limits(self._y, self.ylim, 0.05)

    # -- rendering --------------------------------------------------------------------------------------------------

    def svg(self) -> str:
        """The axes as SVG elements (frame, grid, ticks, labels and the clipped data)."""
        left, top, width, height = self.box
        (x0, x1), (y0, y1) = self.limits()

        def sx(x):
            return (np.asarray(x, dtype=float) - x0) * (width / (x1 - x0))

        def sy(y):
            return height - (np.asarray(y, dtype=float) - y0) * (height / (y1 - y0))

        out = [f'<g transform="translate({left:.1f} {top:.1f})">']
        if self.background:
            out.append(f'<rect width="{width:.1f}" height="{height:.1f}" fill="{self.background}"/>')
        ticks, step = nice_ticks(x0, x1, max(5, int(width // 75)))
        xticks = list(zip(ticks, tick_labels(ticks, step)))
        if self.yticks is not None:
            yticks = list(zip(*self.yticks))
        else:
            ticks, step = nice_ticks(y0, y1, max(5, int(height // 32)))
            yticks = list(zip(ticks, tick_labels(ticks, step)))
        grid = []
        if 'x' in self.grid:
            grid += [f'M{float(sx(t)):.1f} 0V{height:.1f}' for t, _ in xticks]
        if 'y' in self.grid:
            grid += [f'M0 {float(sy(t)):.1f}H{width:.1f}' for t, _ in yticks]
        # the data, clipped to the plotting area by a nested svg
        out.append(f'<svg width="{width:.1f}" height="{height:.1f}" overflow="hidden">')
        # shaded spans under the grid, the data over it, the labels last (outside the clipping)
        spans = [self._item_svg(item, sx, sy, width, height) for item in self._items if item[0] == 'span']
        if not self.zoom_x:
            out += spans
        if grid:
            out.append(f'<path class="grid" d="{"".join(grid)}" stroke="#000" stroke-opacity="0.12" '
                       'stroke-width="1"/>')
        data = [self._item_svg(item, sx, sy, width, height) for item in self._items if item[0] not in ('span', 'text')]
        if self.zoom_x:       # spans (above the grid, which hides while zoomed) and data: the group the script scales
            data = spans + data
            out.append(f'<g class="zx" data-x0="{x0!r}" data-x1="{x1!r}" data-w="{width:.1f}">' + ''.join(data)
                       + '</g>')
        else:
            out += data
        out.append('</svg>')
        out.append(f'<rect width="{width:.1f}" height="{height:.1f}" fill="none" stroke="#888" stroke-width="1"/>')
        font = f'font-size="{TICK_FONT}" fill="#333"'
        if self.show_xticks:
            zoom = f' class="xt" data-w="{width:.1f}" data-y="{height + 14:.1f}"' if self.zoom_x else ''
            out.append(f'<g{zoom} text-anchor="middle" {font}>' + ''.join(
                f'<text x="{float(sx(t)):.1f}" y="{height + 14:.1f}">{_esc(label)}</text>' for t, label in xticks)
                + '</g>')
        out.append(f'<g text-anchor="end" {font}>' + ''.join(
            f'<text x="-5" y="{float(sy(t)) + 4:.1f}">{_esc(label)}</text>' for t, label in yticks
            if y0 - 1e-9 * abs(y1 - y0) <= t <= y1 + 1e-9 * abs(y1 - y0)) + '</g>')
        if self.xlabel:
            out.append(f'<text x="{width / 2:.1f}" y="{height + 31:.1f}" text-anchor="middle" '
                       f'font-size="{LABEL_FONT}">{_esc(self.xlabel)}</text>')
        if self.ylabel:
            out.append(f'<text transform="translate({-self._ylabel_offset(yticks):.1f} {height / 2:.1f}) '
                       f'rotate(-90)" text-anchor="middle" font-size="{LABEL_FONT}">{_esc(self.ylabel)}</text>')
        if self.title:
            out.append(f'<text x="{width / 2:.1f}" y="-7" text-anchor="middle" font-size="{LABEL_FONT}" '
                       f'font-weight="bold">{_esc(self.title)}</text>')
        texts = ''.join(self._item_svg(item, sx, sy, width, height) for item in self._items if item[0] == 'text')
        out.append(f'<g class="zt">{texts}</g>' if self.zoom_x else texts)    # hidden while zoomed (not moved)
        out.append('</g>')
        return ''.join(out)

    @staticmethod
    def _ylabel_offset(yticks) -> float:
        longest = max((len(label) for _, label in yticks), default=3)
        return 12 + longest * 0.6 * TICK_FONT

    def _item_svg(self, item: tuple, sx, sy, width: float, height: float) -> str:
        kind = item[0]
        if kind == 'line':
            _, x, y, colour, line_width, style, opacity = item
            data = _relative(sx(x), sy(y))
            if not data:
                return ''
            return (f'<path d="{data}" fill="none" stroke="{colour}" stroke-width="{line_width:g}"{_dash(style)}'
                    f'{_opacity("stroke", opacity)} stroke-linejoin="round"/>')
        if kind == 'points':
            _, x, y, colour, size, opacity = item
            px, py = sx(x), sy(y)
            keep = np.isfinite(px) & np.isfinite(py)
            if not keep.any():
                return ''
            # each dot a zero-length segment with round caps, reached by a relative move from the previous dot
            px, py = _pixels_in_tenths(px[keep]), _pixels_in_tenths(py[keep])
            steps = _tenths(np.column_stack([np.diff(px), np.diff(py)]).ravel())
            moves = ''.join(f'm{dx} {dy}h0' for dx, dy in zip(steps[::2], steps[1::2]))
            first = ' '.join(_tenths(np.array([px[0], py[0]])))
            dots = f'M{first}h0{moves}'.replace(' -', '-')
            return (f'<path d="{dots}" stroke="{colour}" stroke-width="{size:g}" stroke-linecap="round"'
                    f'{_opacity("stroke", opacity)}/>')
        if kind == 'fill':
            _, x, low, high, colour, opacity = item
            px, pl, ph = sx(x), sy(low), sy(high)
            finite = np.isfinite(px) & np.isfinite(pl) & np.isfinite(ph)
            index = np.flatnonzero(finite)
            shapes = []
            for run in (np.split(index, np.flatnonzero(np.diff(index) > 1) + 1) if index.size else []):
                upper = _coordinates(px[run], ph[run])[0]
                lower = _coordinates(px[run][::-1], pl[run][::-1])[0]
                shapes.append(f'M{upper} L{lower}Z')
            return (f'<path d="{"".join(shapes)}" fill="{colour}"{_opacity("fill", opacity)}/>') if shapes else ''
        if kind == 'span':
            _, a, b, c, d, colour, opacity = item
            if a is not None:
                left, right = sorted((float(sx(a)), float(sx(b))))
                return (f'<rect x="{left:.1f}" width="{right - left:.1f}" height="{height:.1f}" fill="{colour}"'
                        f'{_opacity("fill", opacity)}/>')
            upper, lower = sorted((float(sy(d)), float(sy(c))))
            return (f'<rect y="{upper:.1f}" width="{width:.1f}" height="{lower - upper:.1f}" fill="{colour}"'
                    f'{_opacity("fill", opacity)}/>')
        if kind == 'rule':
            _, x, y, colour, line_width, style = item
            path = f'M{float(sx(x)):.1f} 0V{height:.1f}' if x is not None else f'M0 {float(sy(y)):.1f}H{width:.1f}'
            return f'<path d="{path}" stroke="{colour}" stroke-width="{line_width:g}"{_dash(style)}/>'
        if kind == 'bars':
            _, positions, starts, ends, bar_height, colour, opacity = item
            rects = []
            for position, start, end in zip(positions, starts, ends):
                if not (np.isfinite(start) and np.isfinite(end)):
                    continue
                left, right = sorted((float(sx(start)), float(sx(end))))
                upper = float(sy(position + bar_height / 2))
                rects.append(f'<rect x="{left:.1f}" y="{upper:.1f}" width="{right - left:.1f}" '
                             f'height="{float(sy(position - bar_height / 2)) - upper:.1f}"/>')
            return f'<g fill="{colour}"{_opacity("fill", opacity)}>' + ''.join(rects) + '</g>'
        if kind == 'marker':
            _, x, y, shape, colour, size = item
            px, py = float(sx(x)), float(sy(y))
            back = size if shape == '>' else -size
            return (f'<path d="M{px:.1f} {py:.1f}L{px - back:.1f} {py - size / 2:.1f}L{px - back:.1f} '
                    f'{py + size / 2:.1f}Z" fill="{colour}"/>')
        _, x, y, text, colour, size, anchor, dx, dy, bold, y_fraction = item
        px = float(sx(x)) + dx
        py = (height * (1 - y) if y_fraction else float(sy(y))) + dy
        weight = ' font-weight="bold"' if bold else ''
        return (f'<text x="{px:.1f}" y="{py:.1f}" text-anchor="{anchor}" font-size="{size:g}" fill="{colour}"'
                f'{weight}>{_esc(text)}</text>')


def _dash(style: str) -> str:
    dash = DASHES.get(style)
    return f' stroke-dasharray="{dash}"' if dash else ''


def _opacity(what: str, opacity: float) -> str:
    return f' {what}-opacity="{opacity:g}"' if opacity < 1 else ''


class Figure:
    """A set of axes drawn as one inline SVG with an HTML legend above it.

    Parameters
    ----------
    height : float [px]
        Height of the view box (its width is :data:`WIDTH`).
    """

    def __init__(self, height: float):
        self.height = float(height)
        self.axes: list[Axes] = []

    def add_axes(self, left: float, top: float, right: float, bottom: float) -> Axes:
        """Axes with these margins [px] from the view box's edges."""
        axes = Axes(left, top, WIDTH - left - right, self.height - top - bottom)
        self.axes.append(axes)
        return axes

    def grid(self, rows: int = 1, columns: int = 1, *, left: float = 70, right: float = 14, top: float = 12,
             bottom: float = 42, row_gap: float = 14, column_gap: float = 40,
             height_ratios: Sequence[float] | None = None, share_x: bool = True) -> list[Axes]:
        """A rows x columns grid of axes (row by row) within these margins and gaps [px]; the rows share their x
        limits when `share_x`, and only the bottom row shows x tick labels then."""
        ratios = list(height_ratios or [1.0] * rows)
        free_height = self.height - top - bottom - row_gap * (rows - 1)
        width = (WIDTH - left - right - column_gap * (columns - 1)) / columns
        made, y = [], top
        for row in range(rows):
            height = free_height * ratios[row] / sum(ratios)
            for column in range(columns):
                axes = Axes(left + column * (width + column_gap), y, width, height)
                made.append(axes)
            y += height + row_gap
        self.axes += made
        if share_x and rows > 1:
            for column in range(columns):
                below = made[(rows - 1) * columns + column]
                below._above = [made[row * columns + column] for row in range(rows - 1)]
                for axes in below._above:
                    axes.shared = below
                    axes.show_xticks = False
        return made

    def html(self, alt: str) -> str:
        """The figure as HTML: a legend of every labelled item, then the inline SVG (with `alt` as its title)."""
        keys, seen = [], set()
        for axes in self.axes:
            for label, kind, style in axes.legend:
                if label not in seen:
                    seen.add(label)
                    keys.append(_legend_key(label, kind, style))
        legend = f'<div class="legend">{"".join(keys)}</div>' if keys else ''
        body = ''.join(axes.svg() for axes in self.axes)
        zoom = next((axes for axes in self.axes if axes.zoom_x), None)
        extra = ''
        if zoom is not None:
            (x0, x1), _ = zoom.limits()
            extra = f' zoom" data-x0="{x0!r}" data-x1="{x1!r}'
            legend += ('<div class="legend zoomhint">Time axis: Shift + mouse wheel zooms, drag pans, double-click '
                       'shows the whole record again.</div>')
        return (f'<figure class="plot">{legend}<svg class="plot{extra}" viewBox="0 0 {WIDTH} {self.height:.0f}" '
                f'role="img" aria-label="{_esc(alt)}" font-family="inherit"><title>{_esc(alt)}</title>{body}</svg>'
                '</figure>')


#: Pan and zoom of the time axis of every ``svg.zoom`` in the page (:attr:`Axes.zoom_x`), inline and offline: Shift +
#: wheel zooms about the pointer, a drag pans, a double-click resets; the x tick labels are rewritten for the view
#: (1, 2, 2.5 or 5 times a power of ten, as :func:`nice_ticks`).
ZOOM_SCRIPT = """<script>
(function () {
  function ticks(a, b, n) {
    var raw = (b - a) / n, p = Math.pow(10, Math.floor(Math.log10(raw))), s = 10 * p, m = [1, 2, 2.5, 5];
    for (var i = 0; i < m.length; i++) { if (m[i] * p >= raw) { s = m[i] * p; break; } }
    var out = [];
    for (var x = Math.ceil(a / s - 1e-9) * s; x <= b + s * 1e-9; x += s) { out.push(x); }
    return [out, s];
  }
  function view(svg, a, b) {
    svg.aeropendView = [a, b];
    svg.querySelectorAll('g.zx').forEach(function (g) {
      var x0 = +g.dataset.x0, x1 = +g.dataset.x1, w = +g.dataset.w, k = (x1 - x0) / (b - a);
      g.setAttribute('transform', 'translate(' + (-(a - x0) * w / (b - a)) + ' 0) scale(' + k + ' 1)');
    });
    svg.querySelectorAll('g.xt').forEach(function (g) {
      var w = +g.dataset.w, t = ticks(a, b, Math.max(5, Math.floor(w / 75)));
      var digits = 0;
      while (digits < 6 && Math.abs(Math.round(t[1] * Math.pow(10, digits)) - t[1] * Math.pow(10, digits)) > 1e-6) {
        digits++;
      }
      g.innerHTML = t[0].map(function (x) {
        var px = ((x - a) / (b - a) * w).toFixed(1);
        return '<text x="' + px + '" y="' + g.dataset.y + '">' + x.toFixed(digits) + '</text>';
      }).join('');
    });
    svg.classList.toggle('zoomed', a > +svg.dataset.x0 || b < +svg.dataset.x1);
  }
  document.querySelectorAll('svg.zoom').forEach(function (svg) {
    var X0 = +svg.dataset.x0, X1 = +svg.dataset.x1, drag = null;
    svg.aeropendView = [X0, X1];
    function area() { return svg.querySelector('g.zx').parentNode.getBoundingClientRect(); }
    function clamp(a, b) {
      if (b - a >= X1 - X0) { return [X0, X1]; }
      if (a < X0) { b += X0 - a; a = X0; }
      if (b > X1) { a -= b - X1; b = X1; }
      return [a, b];
    }
    svg.addEventListener('wheel', function (e) {
      if (!e.shiftKey) { return; }
      e.preventDefault();
      var r = area(), v = svg.aeropendView, f = (e.deltaY || e.deltaX) < 0 ? 0.8 : 1.25;
      var c = v[0] + Math.min(Math.max((e.clientX - r.left) / r.width, 0), 1) * (v[1] - v[0]);
      var z = clamp(c - (c - v[0]) * f, c + (v[1] - c) * f);
      view(svg, z[0], z[1]);
    }, {passive: false});
    svg.addEventListener('mousedown', function (e) {
      drag = [e.clientX, svg.aeropendView.slice()];
      e.preventDefault();
    });
    window.addEventListener('mouseup', function () { drag = null; });
    svg.addEventListener('mousemove', function (e) {
      if (!drag) { return; }
      var v = drag[1], d = (e.clientX - drag[0]) / area().width * (v[1] - v[0]), z = clamp(v[0] - d, v[1] - d);
      view(svg, z[0], z[1]);
    });
    svg.addEventListener('dblclick', function () { view(svg, X0, X1); });
  });
})();
</script>"""

#: The style the zoom needs: lines keep their width while the group is scaled; what is not moved is hidden.
ZOOM_CSS = """svg.zoom { cursor: ew-resize; } svg.zoom g.zx * { vector-effect: non-scaling-stroke; }
svg.zoomed g.zt, svg.zoomed path.grid { display: none; } .zoomhint { color: #666; font-size: 12px; }
"""


def _legend_key(label: str, kind: str, style: dict) -> str:
    colour = style['colour']
    opacity = style.get('opacity', 1.0)
    if kind == 'line':
        dash = DASHES.get(style.get('style', '-'))
        swatch = (f'<svg width="26" height="10"><path d="M1 5H25" stroke="{colour}" '
                  f'stroke-width="{max(style.get("width", 1.2), 1.2):g}"'
                  + (f' stroke-dasharray="{dash}"' if dash else '') + _opacity('stroke', max(opacity, 0.5))
                  + '/></svg>')
    elif kind == 'points':
        swatch = (f'<svg width="12" height="10"><circle cx="6" cy="5" r="3" fill="{colour}"'
                  f'{_opacity("fill", max(opacity, 0.5))}/></svg>')
    else:
        swatch = (f'<svg width="18" height="10"><rect width="18" height="10" fill="{colour}"'
                  f'{_opacity("fill", max(opacity, 0.35))}/></svg>')
    return f'<span class="key">{swatch}{_esc(label)}</span>'


__all__ = ['Axes', 'Figure', 'WIDTH', 'ZOOM_CSS', 'ZOOM_SCRIPT', 'nice_ticks', 'tick_labels']

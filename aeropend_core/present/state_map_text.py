"""Words and a picture for where the model fails in the state space (:mod:`aeropend_core.diagnosis.state_map`)."""
from __future__ import annotations

import html
import math

from aeropend_core.diagnosis.state_map import StateMap

#: What acts only in such a region, physically: a lead for the user's own effect.
_LOCAL_CAUSES = {
    'angle': 'something that acts only at these angles (a cable or hose pulling, a stop, a rub, a magnet)',
    'angle_opposing_motion': 'a friction only at these angles (a flaw in the bearing race, a rub at this position)',
    'direction': 'something that acts in one direction of motion only (an asymmetric drag, a one-way friction)',
    'thrust': 'something that acts only in this thrust range (propeller stall, a supply that sags, a dead zone)',
}
_QUANTITY = {'angle': 'missing acceleration', 'angle_opposing_motion': 'missing acceleration against the motion',
             'direction': 'missing acceleration', 'thrust': 'missing acceleration'}


def _region(axis) -> str:
    if axis.axis in ('angle', 'angle_opposing_motion'):
        where = f'between {math.degrees(axis.low):.0f} and {math.degrees(axis.high):.0f} deg'
        if axis.axis == 'angle_opposing_motion':
            where += ', against the motion in both directions'
        return where
    if axis.axis == 'direction':
        return 'only while the rod is ' + ' or '.join(axis.region)
    return f'only at {" and ".join(axis.region)} thrust'


def _size(axis) -> str:
    inside = [b for b in axis.bins if b.label in axis.region]
    peak = max(inside, key=lambda b: abs(b.z))
    return f'{peak.mean:+.2g} +- {peak.standard_error:.1g} rad/s^2'


def state_map_sentence(mapped: StateMap | None) -> str:
    """One sentence: where the missing acceleration sits, how big, and what is physically local there."""
    if mapped is None:
        return ''
    if mapped.note:
        return f'Where it fails in the state space: not mapped ({mapped.note}).'
    if not mapped.significant:
        return ('Where it fails in the state space: nowhere in particular (no band of angles, direction of motion '
                'or thrust range holds a missing acceleration beyond its uncertainty).')
    local = mapped.localised
    if not local:
        text = (f'Where it fails in the state space: spread over the states visited (missing acceleration '
                f'{mapped.rms_missing_acceleration:.2g} rad/s^2 RMS over the angle bands), not confined to one band of '
                'angles, one direction of motion or one thrust range.')
        opposing = mapped.axis('angle_opposing_motion')
        if opposing is not None and opposing.bins:
            against = [b for b in opposing.bins if b.z >= 3.0]
            if len(against) >= 0.5 * len(opposing.bins):
                text += (f' It opposes the motion in {len(against)} of {len(opposing.bins)} bands of angle: a '
                         'friction or drag the model lacks.')
        return text
    best = max(local, key=lambda a: a.share)
    others = [a for a in local if a is not best]
    text = (f'Where it fails in the state space: {_region(best)} ({_QUANTITY[best.axis]} {_size(best)}, '
            f'{best.share * 100:.0f} % of its mean square there, in {best.cover * 100:.0f} % of the samples). '
            f'Physically local there: {_LOCAL_CAUSES[best.axis]}.')
    if others:
        text += ' Also confined: ' + '; '.join(_region(a) for a in others) + '.'
    return text


def state_map_lines(diagnosis) -> list[str]:
    """The text summary's lines: the model given, then the model with the selected set."""
    lines = []
    given, selected = getattr(diagnosis, 'state_map', None), getattr(diagnosis, 'state_map_selected', None)
    if given is not None:
        lines.append(state_map_sentence(given))
    if selected is not None:
        sentence = state_map_sentence(selected)
        lines.append('With ' + ' + '.join(selected.model_effects) + ': ' + sentence[0].lower() + sentence[1:])
    return lines


def _cells_svg(mapped: StateMap) -> str:
    """Angle band (rows) x direction of motion (columns), colour by the mean missing acceleration, cells whose mean is
    within 2 standard errors drawn pale."""
    cells = mapped.cells
    if not cells:
        return '<p class="caption">No band held enough samples to map.</p>'
    bands = sorted({(c['angle_low'], c['angle_high']) for c in cells})
    scale = max(abs(c['mean_missing_acceleration']) for c in cells) or 1.0
    row_h, col_w, left, top = 18, 120, 90, 22
    parts = [f'<svg width="{left + 2 * col_w + 10}" '
             f'height="{top + row_h * len(bands) + 10}" role="img" aria-label="missing acceleration map">',
             f'<text x="{left + col_w / 2}" y="14" text-anchor="middle" font-size="12">rising</text>',
             f'<text x="{left + 1.5 * col_w}" y="14" text-anchor="middle" font-size="12">falling</text>']
    for row, (low, high) in enumerate(reversed(bands)):
        y = top + row * row_h
        parts.append(f'<text x="{left - 6}" y="{y + 13}" text-anchor="end" font-size="11">'
                     f'{math.degrees(low):.0f}&ndash;{math.degrees(high):.0f}&deg;</text>')
        for column, direction in enumerate(('rising', 'falling')):
            cell = next((c for c in cells if c['direction'] == direction and c['angle_low'] == low), None)
            x = left + column * col_w
            if cell is None:
                parts.append(f'<rect x="{x}" y="{y}" width="{col_w - 2}" height="{row_h - 2}" fill="#eee"/>')
                continue
            mean, sigma = cell['mean_missing_acceleration'], cell['standard_error']
            strength = min(abs(mean) / scale, 1.0)
            clear = abs(mean) >= 2.0 * sigma
            colour = (f'rgba(200,40,40,{0.15 + 0.85 * strength:.2f})' if mean > 0
                      else f'rgba(40,80,200,{0.15 + 0.85 * strength:.2f})') if clear else '#f4f4f4'
            parts.append(f'<rect x="{x}" y="{y}" width="{col_w - 2}" height="{row_h - 2}" fill="{colour}">'
                         f'<title>{math.degrees(low):.0f}-{math.degrees(high):.0f} deg, {direction}: '
                         f'{mean:+.3g} +- {sigma:.2g} rad/s^2 ({cell["samples"]} samples)</title></rect>')
            parts.append(f'<text x="{x + col_w / 2}" y="{y + 13}" text-anchor="middle" font-size="10">'
                         f'{mean:+.2f}</text>')
    parts.append('</svg>')
    return ''.join(parts)


def state_map_html(diagnosis) -> str:
    """The report's section: the sentence and the map, for the model given and with the selected set."""
    given, selected = getattr(diagnosis, 'state_map', None), getattr(diagnosis, 'state_map_selected', None)
    if given is None:
        return ''
    parts = ['<h2 id="state-map">Where it fails in the state space</h2><p class="caption">The angular acceleration '
             'the model lacks at each state (from the free-run residual: r&Prime; + k cos(angle) r + c r&prime;), '
             'mean per 5&deg; band of angle and direction of motion, in rad/s&sup2;. Red: the rig accelerates more '
             'than the model (upwards), blue: less; pale: within 2&sigma; of zero. Hover a cell for its '
             '&plusmn;.</p>']
    for label, mapped in (('The model given', given), ('With the selected set', selected)):
        if mapped is None:
            continue
        parts.append(f'<h3>{html.escape(label)} ({html.escape(" + ".join(("nominal",) + mapped.model_effects))})'
                     f'</h3><p>{html.escape(state_map_sentence(mapped))}</p>' + _cells_svg(mapped))
    return ''.join(parts)


__all__ = ['state_map_sentence', 'state_map_lines', 'state_map_html']

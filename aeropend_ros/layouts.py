"""The shipped Foxglove and PlotJuggler layouts of the live graph (and of recorded bags), generated from the topic
contract so that they name only what the nodes publish.

``config/aeropend.foxglove.json`` (Foxglove: *Layouts*, *Import from file*; built with foxglove-sdk's own layout
classes, ``foxglove.layouts``) and ``config/aeropend.plotjuggler.xml`` (PlotJuggler: *Layout*, *Load*; with the ROS 2
plugin or an MCAP bag) show: the angle, the armature voltage Va and current Ia (and the duty), every identified
parameter with its ±1σ band (value, value + σ, value − σ), the held-out fit %, RMS error against the measurement
noise, and the diagnostics.

Each parameter has its own topic, ``/aeropend/parameters/<name>`` (``sensor_msgs/JointState`` with the fixed field
names :data:`aeropend_ros.topics.PARAMETER_FIELDS`: ``value``, ``lower``, ``upper``, ``sigma``, ``data_flagged``,
``trend_change``, ``drifting``), so the band is three plain series by path in both tools: in Foxglove
``/aeropend/parameters/damping.position[0]`` (value), ``[1]`` (lower = value − σ) and ``[2]`` (upper = value + σ)
(message path syntax: topic, field, array index), in PlotJuggler ``/aeropend/parameters/damping/value/position``,
``.../lower/position`` and ``.../upper/position`` (its JointState parser names each entry). No script, no custom
math. A parameter whose σ is unknown (NaN, e.g. ``armature_resistance`` from the motor observer) shows no band.

Regenerate after changing the topics: ``python -m aeropend_ros.layouts`` (tests/test_foxglove.py checks that the
shipped files are the generated ones).
"""
from __future__ import annotations

import json
import sys
from pathlib import Path
from xml.sax.saxutils import quoteattr

from aeropend_ros.topics import PARAMETER_FIELDS, SAMPLE_NAMES, SAMPLES_TOPIC, parameter_topic

FOXGLOVE_FILE = 'aeropend.foxglove.json'
PLOTJUGGLER_FILE = 'aeropend.plotjuggler.xml'

PARAMETERS_TOPIC = '/aeropend/identification/parameters'
FIT_TOPIC = '/aeropend/identification/fit'
DIAGNOSTICS_TOPIC = '/diagnostics'

#: ``name`` of the fit messages, in order (identification_node publishes them so).
FIT_NAMES = ('fit_percent', 'rms_error', 'noise_rms', 'held_out_seconds', 'compute_time', 'window_start')

#: Symbols shown next to the nominal parameters' names (the names and units come from aeropend_core.model.names).
_SYMBOLS = {'gravity_stiffness': 'mgd/J', 'damping': 'c/J', 'thrust_gain': 'k', 'thrust_coefficient': 'Kq',
            'armature_resistance': 'R'}


def _nominal_bands() -> dict[str, str]:
    """The nominal and derived parameters as published (nominal first), titled with symbol and SI unit."""
    from aeropend_core.model.effects import parameter_unit
    from aeropend_core.model.names import NOMINAL_PARAMETERS
    names = [*NOMINAL_PARAMETERS, 'thrust_coefficient']
    return {name: f'{_SYMBOLS.get(name, name)} [{parameter_unit(name)}]' for name in names}


def _effect_bands() -> dict[str, str]:
    """Every built-in catalog effect's parameters (published when the model has that effect), with their unit: the
    shipped layouts do not depend on the user or discovered effects a process happens to have registered."""
    from aeropend_core.model.effects import CATALOG
    bands = {}
    for effect in CATALOG.values():
        if not effect.builtin:
            continue
        for parameter in effect.parameters:
            bands[parameter.name] = f'{effect.name}: {parameter.name} [{parameter.unit}]'
    return bands


def band_parameters() -> dict[str, str]:
    """Name -> plot title of every parameter drawn with its band (nominal, then the effects')."""
    return {**_nominal_bands(), **_effect_bands()}


BAND_PARAMETERS = tuple(band_parameters())


def published_fields() -> dict[str, tuple[str, ...]]:
    """Topic -> the ``name`` entries its JointState messages carry (the parameters: every name that can appear; each
    parameter's own topic: :data:`PARAMETER_FIELDS`)."""
    fields = {SAMPLES_TOPIC: tuple(SAMPLE_NAMES), PARAMETERS_TOPIC: BAND_PARAMETERS, FIT_TOPIC: FIT_NAMES}
    fields.update({parameter_topic(name): PARAMETER_FIELDS for name in BAND_PARAMETERS})
    return fields


def _sample(name: str) -> str:
    return f'{SAMPLES_TOPIC}.position[{SAMPLE_NAMES.index(name)}]'


def _fit(name: str) -> str:
    return f'{FIT_TOPIC}.position[{FIT_NAMES.index(name)}]'


def foxglove_layout():
    """The Foxglove layout (``foxglove.layouts.Layout``)."""
    import foxglove.layouts as fl

    def plot(title: str, series: list[tuple[str, str, str, str]], y_label: str = '') -> fl.PlotPanel:
        # every message by acquisition time (header.stamp: the window's end for the results)
        return fl.PlotPanel(title=title, config=fl.PlotConfig(
            paths=[fl.PlotSeries(value=path, label=label, color=color, line_style=style, timestamp_method='headerStamp')
                   for path, label, color, style in series],
            show_legend=True, legend_display='top', y_axis_label=y_label or None))

    def column(panels) -> fl.SplitContainer:
        return fl.SplitContainer(direction='column', items=[fl.SplitItem(content=panel) for panel in panels])

    def band(name: str, title: str) -> fl.PlotPanel:
        topic = parameter_topic(name)

        def field(key: str) -> str:
            return f'{topic}.position[{PARAMETER_FIELDS.index(key)}]'
        return plot(title, [(field('value'), name, '#1f63b4', 'solid'),
                            (field('upper'), '+1σ', '#7fa8d9', 'dashed'),
                            (field('lower'), '−1σ', '#7fa8d9', 'dashed')])

    signals = column([
        plot('Rod angle [rad]', [(_sample('angle'), 'angle [rad]', '#333333', 'solid')]),
        plot('Armature voltage Va [V] and current Ia [A]', [
            (_sample('armature_voltage'), 'Va [V]', '#7b3294', 'solid'),
            (_sample('armature_current'), 'Ia [A]', '#e66101', 'solid'),
            (_sample('duty'), 'duty [0..1]', '#999999', 'dashed')]),
        plot('Held-out fit [%] (MATLAB compare NRMSE; 100 = perfect)', [(_fit('fit_percent'), 'fit %', '#1a9641',
                                                                       'solid')]),
        plot('Held-out RMS error vs measurement noise [rad]', [
            (_fit('rms_error'), 'RMS error [rad]', '#d7301f', 'solid'),
            (_fit('noise_rms'), 'noise RMS [rad]', '#555555', 'dashed')]),
    ])
    nominal = column([band(name, f'{title} ± 1σ') for name, title in _nominal_bands().items()])
    effects = column([band(name, f'{title} ± 1σ') for name, title in _effect_bands().items()])
    colours = ('#1f63b4', '#1a9641', '#e66101', '#7b3294')
    flags = plot('Drift (1 = the trend over the windows is a drift) and data flagged (1 = repaired or filled)', [
        *((f'{parameter_topic(name)}.position[{PARAMETER_FIELDS.index("drifting")}]', f'{name} drifting', colour,
           'solid') for name, colour in zip(_nominal_bands(), colours)),
        (f'{parameter_topic("thrust_gain")}.position[{PARAMETER_FIELDS.index("data_flagged")}]', 'window data flagged',
         '#d7301f', 'dashed')])
    diagnostics = fl.SplitContainer(direction='row', items=[
        fl.SplitItem(content=flags),
        fl.SplitItem(content=fl.DiagnosticsSummaryPanel(title='Diagnostics', config=fl.DiagnosticsSummaryConfig(
            topic_to_render=DIAGNOSTICS_TOPIC, sort_by_level=True))),
        fl.SplitItem(content=fl.DiagnosticsDetailPanel(title='Diagnostics detail', config=fl.DiagnosticsDetailConfig(
            topic_to_render=DIAGNOSTICS_TOPIC)))])
    content = fl.SplitContainer(direction='row', items=[
        fl.SplitItem(proportion=1, content=signals),
        fl.SplitItem(proportion=1, content=fl.TabContainer(tabs=[
            fl.TabItem(title='Parameters ± 1σ', content=nominal),
            fl.TabItem(title='Effect parameters ± 1σ', content=effects),
            fl.TabItem(title='Diagnostics', content=diagnostics)])),
    ])
    return fl.Layout(content=content)


def foxglove_layout_json() -> str:
    """The layout as the JSON text of the shipped file (indented, ending in a newline)."""
    return json.dumps(json.loads(foxglove_layout().to_json()), indent=1, ensure_ascii=False) + '\n'


def plotjuggler_layout_xml() -> str:
    """The PlotJuggler layout (XML; PlotJuggler 3: ROS 2 topic subscriber or an MCAP/rosbag2 file)."""
    def curve(name: str, color: str) -> str:
        return f'       <curve name={quoteattr(name)} color="{color}"/>\n'

    def plot(curves: list[tuple[str, str]]) -> str:
        return ('      <plot mode="TimeSeries" flip_x="false" flip_y="false" style="Lines">\n'
                '       <range left="0" right="1" top="1" bottom="0"/>\n'
                '       <limitY/>\n' + ''.join(curve(n, c) for n, c in curves) + '      </plot>\n')

    def area(plots: list[str]) -> str:
        sizes = ';'.join([f'{1.0 / len(plots):.6f}'] * len(plots))
        return (f'     <DockSplitter orientation="-" count="{len(plots)}" sizes="{sizes}">\n'
                + ''.join(f'      <DockArea name="...">\n{p}      </DockArea>\n' for p in plots)
                + '     </DockSplitter>\n')

    def tab(name: str, plots: list[str]) -> str:
        return (f'   <Tab containers="1" tab_name={quoteattr(name)}>\n    <Container>\n' + area(plots)
                + '    </Container>\n   </Tab>\n')

    samples = SAMPLES_TOPIC
    signals = [plot([(f'{samples}/angle/position', '#333333')]),
               plot([(f'{samples}/armature_voltage/position', '#7b3294'),
                     (f'{samples}/armature_current/position', '#e66101'),
                     (f'{samples}/duty/position', '#999999')]),
               plot([(f'{FIT_TOPIC}/fit_percent/position', '#1a9641')]),
               plot([(f'{FIT_TOPIC}/rms_error/position', '#d7301f'), (f'{FIT_TOPIC}/noise_rms/position', '#555555')])]
    def band(name: str) -> str:
        topic = parameter_topic(name)
        return plot([(f'{topic}/value/position', '#1f63b4'), (f'{topic}/upper/position', '#7fa8d9'),
                     (f'{topic}/lower/position', '#7fa8d9')])

    nominal = [band(name) for name in _nominal_bands()]
    effects = [band(name) for name in _effect_bands()]
    topics = [samples, PARAMETERS_TOPIC, FIT_TOPIC, DIAGNOSTICS_TOPIC, '/aeropend/duty_cmd',
              '/aeropend/identification/coefficients', *(parameter_topic(name) for name in BAND_PARAMETERS)]
    return ('<?xml version=\'1.0\' encoding=\'UTF-8\'?>\n'
            '<!-- aeropend: angle, Va, Ia, fit %, every identified parameter with its +-1 sigma band. Generated by '
            'aeropend_ros/layouts.py; load with Layout > Load (ROS 2 topic subscriber or an MCAP bag). -->\n'
            '<root>\n <tabbed_widget name="Main Window" parent="main_window">\n'
            + tab('signals and fit', signals) + tab('parameters +-1 sigma', nominal)
            + tab('effect parameters +-1 sigma', effects)
            + '  <currentTabIndex index="0"/>\n </tabbed_widget>\n'
            ' <use_relative_time_offset enabled="1"/>\n <Plugins>\n'
            '  <plugin ID="ROS2 Topic Subscriber">\n   <use_header_stamp value="true"/>\n   <selected_topics>\n'
            + ''.join(f'    <topic name={quoteattr(t)}/>\n' for t in topics)
            + '   </selected_topics>\n  </plugin>\n </Plugins>\n</root>\n')


def write_layouts(folder: Path) -> list[Path]:
    """Write both layout files into `folder`; returns their paths."""
    foxglove_path = folder / FOXGLOVE_FILE
    plotjuggler_path = folder / PLOTJUGGLER_FILE
    foxglove_path.write_text(foxglove_layout_json(), encoding='utf-8')
    plotjuggler_path.write_text(plotjuggler_layout_xml(), encoding='utf-8')
    return [foxglove_path, plotjuggler_path]


if __name__ == '__main__':
    root = Path(__file__).resolve().parents[1] / 'config'
    for written in write_layouts(Path(sys.argv[1]) if len(sys.argv) > 1 else root):
        print(written)

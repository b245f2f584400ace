"""Argument checks shared by the verbs (not a verb: not listed in VERBS)."""
from __future__ import annotations

from aeropend_core.errors import AeropendError


#: What a name may end in for an option that writes an HTML page.
HTML_SUFFIXES = ('.html', '.htm')


def check_report_path(path: str | None, option: str = '--report') -> None:
    """An output file can be written to `path` (refused before any work: a folder, a missing folder, a device, a
    named pipe, a symbolic link loop; see :func:`aeropend_core.io.paths.output_target`). ``--report`` writes an
    HTML page: a name not ending in .html or .htm (``out.png``, ``report.pdf``) is refused, never written as HTML
    under a picture's name."""
    if path and option == '--report' and not path.lower().endswith(HTML_SUFFIXES):
        import os
        stem = os.path.splitext(path)[0] or 'report'
        raise AeropendError(f'--report {path}: the report is one self-contained HTML page (its pictures inline), '
                            f'not a {os.path.splitext(path)[1] or "file without a suffix"}; name it .html '
                            f'(e.g. --report {stem}.html) and open it in a browser')
    if path:
        from aeropend_core.io.paths import output_target
        output_target(path, option)


def print_findings(verb: str, findings) -> None:
    """Every data-quality finding as one line on standard error: ``aeropend VERB: warning: <message> [code,
    severity]`` (repairs too: nothing is changed silently)."""
    import sys
    for finding in findings:
        if finding.severity != 'refused':
            print(f'aeropend {verb}: warning: {finding.message} [{finding.code}, {finding.severity}]', file=sys.stderr,
                  flush=True)


def add_sample_rate_argument(parser) -> None:
    """``--sample-rate HZ``: the acquisition rate the data must have (the rig's 490 Hz by default)."""
    from aeropend_core.model.parameters import SAMPLE_TIME
    parser.add_argument('--sample-rate', type=float, default=None, metavar='HZ',
                        help=f'acquisition rate of the recording [Hz], 20 Hz to 2 kHz (default: the rate an `aeropend '
                             f'import` or --profile states, else the rig\'s {1.0 / SAMPLE_TIME:g}); a record at '
                             'another rate is refused, one stamped in ms converted')
    parser.add_argument('--profile', metavar='PROFILE.yaml',
                        help='read DATA as a log written by another rig through this log profile (columns, units, '
                             'clock; see docs/log-import.md and config/profiles/)')


def sample_time_from(args, stated_rate: float | None = None) -> float:
    """The declared sample time [s]: --sample-rate, else `stated_rate` [Hz] (an imported record's or a profile's),
    else the rig's 1/490 s; refused unless a finite rate > 0."""
    import math

    from aeropend_core.model.parameters import SAMPLE_TIME
    rate = args.sample_rate if getattr(args, 'sample_rate', None) is not None else stated_rate
    if rate is None:
        return SAMPLE_TIME
    if not (math.isfinite(rate) and 0 < rate <= 1e6):
        raise AeropendError(f'--sample-rate must be a rate in Hz in (0, 1e6], got {rate}')
    return 1.0 / rate


def load_for_analysis(args, verb: str, path=None):
    """The recording of ``args.data`` (or `path`, e.g. a validation record of the same rig) through the data-quality
    gate: read through ``--profile`` when given (a foreign log), else as our CSV/bag, at the rate --sample-rate, the
    profile or the import metadata states.

    Returns
    -------
    Recording
        The repaired recording (its findings say every repair and warning, the import's notes included).
    """
    from aeropend_core.io.recording import Recording, load_recording
    path = args.data if path is None else path
    if getattr(args, 'profile', None):
        from aeropend_core.io.log_profile import import_log, load_profile
        from aeropend_core.signals.quality import Finding, check_recording
        profile = load_profile(args.profile)
        columns, metadata = import_log(path, profile, args.profile)
        notes = tuple(Finding('log_profile', 'warning', f'{path}: {note} (profile {args.profile})')
                      for note in metadata['notes'])
        recording = Recording(columns['t'], {k: v for k, v in columns.items() if k != 't'}, str(path), notes)
        return check_recording(recording, sample_time=sample_time_from(args, metadata['sample_rate_hz'])).recording
    from aeropend_core.io.log_profile import read_import_metadata
    metadata = read_import_metadata(path) if str(path).lower().endswith('.csv') else None
    stated = metadata.get('sample_rate_hz') if metadata else None
    return load_recording(path, sample_time=sample_time_from(args, stated))


def add_json_argument(parser, what: str) -> None:
    """``--json [FILE]``, the same on every verb: `what` as JSON to FILE, or to standard output with ``-`` or no FILE
    (standard output then carries the JSON only). Checked with :func:`check_json_target` before any work."""
    parser.add_argument('--json', nargs='?', const='-', default=None, metavar='FILE',
                        help=f'write {what} as JSON to FILE (- or no FILE: to standard output, which then carries '
                             'the JSON only)')


def text_aside_from_json(target: str | None):
    """A context in which printed text goes to standard error when ``--json -`` makes standard output carry the JSON
    only (a no-op context otherwise)."""
    import contextlib
    import sys
    return contextlib.redirect_stdout(sys.stderr) if target == '-' else contextlib.nullcontext()


def check_json_target(target: str | None) -> None:
    """Refuse a ``--json`` FILE that cannot be written (a folder, a missing folder, a device, ...) before any work;
    ``-`` and None (no --json) pass."""
    if target and target != '-':
        check_report_path(target, '--json')


def add_time_range_arguments(parser) -> None:
    """``--start S`` and ``--stop S``: analyse only the samples with start <= t < stop [s] of the recording."""
    parser.add_argument('--start', type=float, default=None, help='use samples from this time [s]')
    parser.add_argument('--stop', type=float, default=None, help='use samples before this time [s]')


def time_window(recording, start: float | None, stop: float | None):
    """The samples of `recording` in [start, stop) [s], with clear errors for a non-finite, empty or inverted range.

    Parameters
    ----------
    recording : Recording [-]
    start, stop : float or None [s]
        Bounds of the range in the recording's time; None: open on that side.
    """
    import math

    import numpy as np
    for option, value in (('--start', start), ('--stop', stop)):
        if value is not None and not math.isfinite(value):
            raise AeropendError(f'{option} must be a finite time in seconds, got {value}')
    if start is not None and stop is not None and not start < stop:
        raise AeropendError(f'--start {start:g} s must be before --stop {stop:g} s')
    if start is None and stop is None:
        return recording
    window = recording.window(-np.inf if start is None else start, np.inf if stop is None else stop)
    if len(window) == 0:
        span = f'{recording.time[0]:g} s to {recording.time[-1]:g} s' if len(recording) else 'no samples'
        asked = ' and '.join(f'{o} {v:g} s' for o, v in (('--start', start), ('--stop', stop)) if v is not None)
        raise AeropendError(f'no samples with {asked}; the recording spans {span}')
    return window


def add_calibration_argument(parser) -> None:
    """``--calibration FILE``: the rig's calibration YAML; its measurement-chain values are held in the model."""
    parser.add_argument('--calibration', metavar='FILE.yaml',
                        help="the rig's calibration file (config/serial_bridge_node.yaml, written by `aeropend "
                             "calibrate ... --write`): its angle_filter_delay [s] holds the angle filter at that "
                             'value (reported as fixed from calibration); --fix angle_filter=... overrides it')


def add_fix_argument(parser) -> None:
    """``--fix EFFECT=VALUE`` (repeatable), the same on every verb that fits the model: an effect with a known
    hardware value, held in the model instead of fitted."""
    parser.add_argument('--fix', action='append', default=[], metavar='EFFECT=VALUE',
                        help='effect with a known hardware value, held in the model (repeatable), e.g. '
                             'angle_filter=0.0141 (the rig\'s RC filter delay [s]) or NAME.PARAMETER=VALUE')


def fixed_effects(fix: list[str], add: list[str]) -> dict[str, dict[str, float]]:
    """The ``--fix`` effects as ``{effect: {parameter: value}}`` [SI], refused when one is also in ``--add``."""
    from aeropend_core.model.effects import parse_effect_assignments
    fixed = parse_effect_assignments(fix)
    both = sorted(set(fixed) & set(add))
    if both:
        raise AeropendError(f'{", ".join(both)} given with both --add and --fix; --fix already puts it in the model')
    return fixed


def calibration_fixed(path: str | None, fixed: dict[str, dict[str, float]]) -> tuple[dict, dict[str, str], str]:
    """Merge a calibration file's measurement chain into the ``--fix`` effects.

    Parameters
    ----------
    path : str or None [-]
        The ``--calibration`` file (None: nothing to merge).
    fixed : dict [SI unit of each parameter]
        ``--fix`` effects, ``{effect: {parameter: value}}`` (they win over the file).

    Returns
    -------
    fixed : dict
        The merged effects to hold.
    fixed_from : dict of str -> str
        ``{effect: 'calibration file PATH'}`` for the effects the file gave.
    message : str
        One line saying what the file fixed (empty when nothing).
    """
    if not path:
        return fixed, {}, ''
    from aeropend_core.model.effects import resolve_effects
    from aeropend_core.rig.calibration import ANGLE_FILTER_KEY, read_measurement_chain
    chain = read_measurement_chain(path)
    where = f'calibration file {path}'
    if chain.angle_filter_delay is None:
        return fixed, {}, f'{path} states no {ANGLE_FILTER_KEY}: the angle filter stays a candidate'
    if 'angle_filter' in fixed:
        return fixed, {}, (f'--fix angle_filter overrides the {ANGLE_FILTER_KEY} of {path} '
                           f'({chain.angle_filter_delay:g} s)')
    merged = {**fixed, **resolve_effects({'angle_filter': chain.angle_filter_delay})}
    what = ('no filter on the angle (delay 0 s)' if chain.angle_filter_delay == 0.0 else
            f'angle filter delay {chain.angle_filter_delay * 1e3:.2f} ms')
    return merged, {'angle_filter': where}, f'{what} fixed from {where}'


def save_beside_bag(diagnosis, bag_folder) -> list[str]:
    """Save a run's diagnosis beside its bag: ``<bag>.diagnosis.json`` (as ``aeropend diagnose --json``, its
    ``schema`` key ``aeropend.diagnosis/1``) and ``<bag>.report.html`` (as ``--report``), so that what the run
    printed is kept with the record. Returns the paths written.

    Parameters
    ----------
    diagnosis : Diagnosis [-]
        The finished diagnosis of the bag.
    bag_folder : str or PathLike [-]
        The bag folder (``bags/aeropend_20261206_210000``); the files go next to it, not into it (the bag's files
        and its SHA-256 stay as recorded).
    """
    from pathlib import Path

    from aeropend_core.present.json_output import write_json
    from aeropend_core.present.report import write_report
    folder = Path(bag_folder)
    json_path, report_path = (folder.with_name(folder.name + suffix) for suffix in ('.diagnosis.json', '.report.html'))
    write_json(str(json_path), diagnosis.to_dict())
    return [str(json_path), str(write_report(diagnosis, str(report_path), source=str(folder)))]

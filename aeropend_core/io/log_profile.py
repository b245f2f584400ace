"""Logs as they were recorded: a small YAML "log profile" maps a foreign log's columns onto a recording.

A profile (``docs/log-import.md``; shipped ones in ``config/profiles/``)::

    name: Arduino logger, AS5040 and A0 current sense
    format: csv                 # csv (default) or bag (our MCAP bags: the columns are already ours)
    delimiter: ','              # optional; csv only
    clock:
      column: pc_time           # the time column (omit: time from the sample order at `rate`)
      kind: datetime            # datetime | seconds | milliseconds | microseconds
      source: host              # host (stamped by a PC: buffering expected) or device
      rate: 22.2816             # the device's line rate [Hz] (optional with a time column)
    columns:
      duty: {column: pwm, scale: 0.00392157}                  # SI = raw x scale + offset
      angle: {column: enc, unit: count, counts_per_turn: 1024, zero: 40, wrap: true}
      armature_current: {column: A0, unit: mA}                # a unit pint knows
      armature_voltage: {column: va, unit: V}

Quantities: ``duty`` [1], ``armature_voltage`` [V], ``armature_current`` [A], ``angle`` [rad]. Each names its
``column`` (header name, or 0-based index) and either a ``unit`` (converted with pint: ``mA``, ``deg``,
``percent``; ``count`` for an angle with ``counts_per_turn`` and ``zero``) or ``scale``/``offset``. ``wrap: true``
unwraps an angle that wraps at a turn. A log without ``armature_voltage`` but with ``duty`` gets Va from the duty by
eq (8), said in the metadata. :func:`import_log` returns the recording and its metadata (the profile, the source
file's SHA-256, what was done); :func:`write_imported` writes it in our CSV format with the metadata as a comment.
"""
from __future__ import annotations

import csv
import datetime as _dt
import difflib
import hashlib
import json
import math
import sys
from pathlib import Path

import numpy as np

from aeropend_core.errors import AeropendError

#: Quantities a profile may map, with their SI unit (pint spelling).
QUANTITIES = {'duty': 'dimensionless', 'armature_voltage': 'volt', 'armature_current': 'ampere', 'angle': 'radian'}
#: A unit to suggest for each quantity.
EXAMPLE_UNITS = {'duty': 'percent', 'armature_voltage': 'mV', 'armature_current': 'mA', 'angle': 'deg'}
#: Keys a profile may have at its top level, in a quantity's entry, and in its clock.
PROFILE_KEYS = {'name', 'format', 'delimiter', 'clock', 'columns', 'description'}
ENTRY_KEYS = {'column', 'unit', 'scale', 'offset', 'counts_per_turn', 'zero', 'wrap'}
CLOCK_KEYS = {'column', 'kind', 'source', 'rate', 'format'}
TIME_KINDS = {'seconds': 1.0, 'milliseconds': 1e-3, 'microseconds': 1e-6, 'datetime': None}


def load_profile(path: str | Path) -> dict:
    """Read and check a log profile (YAML).

    Parameters
    ----------
    path : str or Path [-]

    Returns
    -------
    dict
        The profile as written (checked: known keys, quantities, clock kinds, numbers).

    Raises
    ------
    AeropendError
        Unreadable file, or a profile that names an unknown key, quantity, unit or clock kind.
    """
    import yaml

    from aeropend_core.io.inputs import load_yaml
    path = Path(path)
    try:
        profile = load_yaml(path, 'the profile')                 # a FIFO, device or a too deep YAML: refused
    except OSError as error:
        raise AeropendError(f'cannot read the profile {path}: {error.strerror or error}') from None
    except yaml.YAMLError as error:
        raise AeropendError(f'{path} is not valid YAML: {error}'.splitlines()[0]) from None
    check_profile(profile, str(path))
    return profile


def _unknown(kind: str, names, known, where: str) -> None:
    bad = sorted(set(names) - set(known))
    if bad:
        close = difflib.get_close_matches(bad[0], sorted(known), n=1)
        hint = f' (did you mean {close[0]!r}?)' if close else ''
        raise AeropendError(f'{where}: unknown {kind} {bad[0]!r}{hint}; known: {", ".join(sorted(known))}')


def check_profile(profile, where: str = 'profile') -> None:
    """Refuse a profile that is not a mapping, or names an unknown key, quantity, unit or clock kind."""
    if not isinstance(profile, dict):
        raise AeropendError(f'{where}: a log profile is a YAML mapping with `clock` and `columns`')
    _unknown('key', profile, PROFILE_KEYS, where)
    if profile.get('format', 'csv') not in ('csv', 'bag'):
        raise AeropendError(f'{where}: format must be csv or bag, got {profile.get("format")!r}')
    columns = profile.get('columns') or {}
    if profile.get('format', 'csv') == 'csv' and not columns:
        raise AeropendError(f'{where}: `columns` maps no quantity; map at least angle and duty (or armature_voltage)')
    if not isinstance(columns, dict):
        raise AeropendError(f'{where}: `columns` must map quantity -> {{column: ..., unit: ...}}')
    _unknown('quantity', columns, QUANTITIES, where)
    for quantity, entry in columns.items():
        if not isinstance(entry, dict) or 'column' not in entry:
            raise AeropendError(f'{where}: columns.{quantity} needs `column` (the log\'s column name or index)')
        _unknown(f'key of columns.{quantity}', entry, ENTRY_KEYS, where)
        if 'unit' in entry and ('scale' in entry or 'offset' in entry):
            raise AeropendError(f'{where}: columns.{quantity} gives both unit and scale/offset; give one')
        for key in ('scale', 'offset', 'counts_per_turn', 'zero'):
            if key in entry and not (isinstance(entry[key], (int, float)) and math.isfinite(entry[key])):
                raise AeropendError(f'{where}: columns.{quantity}.{key} must be a finite number, got {entry[key]!r}')
        if 'unit' in entry:
            unit_factor(quantity, entry, where)
    clock = profile.get('clock') or {}
    if not isinstance(clock, dict):
        raise AeropendError(f'{where}: `clock` must be a mapping (column, kind, source, rate)')
    _unknown('key of clock', clock, CLOCK_KEYS, where)
    if 'kind' in clock and clock['kind'] not in TIME_KINDS:
        _unknown('clock kind', [clock['kind']], TIME_KINDS, where)
    if clock.get('source', 'device') not in ('host', 'device'):
        raise AeropendError(f'{where}: clock.source must be host or device, got {clock.get("source")!r}')
    rate = clock.get('rate')
    if rate is not None and not (isinstance(rate, (int, float)) and 0 < rate <= 1e6):
        raise AeropendError(f'{where}: clock.rate must be a rate in Hz in (0, 1e6], got {rate!r}')
    if profile.get('format', 'csv') == 'csv' and 'column' not in clock and rate is None:
        raise AeropendError(f'{where}: the clock needs a time `column` or the device\'s `rate` [Hz]')


def unit_factor(quantity: str, entry: dict, where: str = 'profile') -> float:
    """Factor [SI unit / log unit] of an entry's ``unit`` (pint), ``count`` handled for the angle."""
    unit = str(entry['unit']).strip()
    if unit in ('count', 'counts'):
        if quantity != 'angle' or 'counts_per_turn' not in entry:
            raise AeropendError(f'{where}: columns.{quantity}: unit count needs counts_per_turn (an angle), or give '
                                'scale (SI units per count) and offset instead')
        return 2 * math.pi / float(entry['counts_per_turn'])
    import pint
    registry = _registry()
    try:
        return float(registry.Quantity(1.0, unit).to(QUANTITIES[quantity]).magnitude)
    except pint.UndefinedUnitError:
        raise AeropendError(f'{where}: columns.{quantity}: unknown unit {unit!r}; give a unit such as '
                            f'{EXAMPLE_UNITS[quantity]} or scale/offset') from None
    except pint.DimensionalityError:
        raise AeropendError(f'{where}: columns.{quantity}: unit {unit!r} is not a unit of {quantity} '
                            f'({QUANTITIES[quantity]})') from None


_REGISTRY = []


def _registry():
    import pint
    if not _REGISTRY:
        _REGISTRY.append(pint.UnitRegistry())
    return _REGISTRY[0]


def sha256_of(path: str | Path) -> str:
    """Hex SHA-256 of a file's bytes (a bag folder: of its files' bytes in name order)."""
    digest = hashlib.sha256()
    path = Path(path)
    for part in (sorted(p for p in path.iterdir() if p.is_file()) if path.is_dir() else [path]):
        with open(part, 'rb') as handle:
            for block in iter(lambda: handle.read(1 << 20), b''):
                digest.update(block)
    return digest.hexdigest()


def _read_table(path: Path, delimiter: str | None) -> tuple[list[str], list[list[str]]]:
    try:
        text = path.read_text(encoding='utf-8-sig')
    except OSError as error:
        raise AeropendError(f'cannot read {path}: {error.strerror or error}') from None
    except UnicodeDecodeError:
        raise AeropendError(f'{path} is not a text log; give the CSV the logger wrote') from None
    lines = [line for line in text.splitlines() if line.strip() and not line.lstrip().startswith('#')]
    if len(lines) < 2:
        raise AeropendError(f'{path}: no header and data rows')
    if delimiter is None:
        from aeropend_core.io.profile_guess import sniff_delimiter
        delimiter = sniff_delimiter(lines[0])
    rows = list(csv.reader(lines, delimiter=delimiter))
    header = [h.strip() for h in rows[0]]
    width = len(header)
    body = [r for r in rows[1:] if len(r) == width]
    if len(body) < len(rows) - 1:
        bad = next(i for i, r in enumerate(rows[1:], 1) if len(r) != width)
        if len(body) < 0.99 * (len(rows) - 1):
            raise AeropendError(f'{path}: data row {bad} has {len(rows[bad])} fields, the header {width}; is the '
                                'delimiter right (profile `delimiter`)?')
    return header, body


def _column(header: list[str], body, spec, quantity: str, path: Path) -> list[str]:
    if isinstance(spec, int) and not isinstance(spec, bool):
        if not 0 <= spec < len(header):
            raise AeropendError(f'{path}: the profile maps {quantity} to column index {spec}; the log has '
                                f'{len(header)} columns (0-{len(header) - 1})')
        index = spec
    else:
        if str(spec) not in header:
            close = difflib.get_close_matches(str(spec), header, n=1)
            hint = f' (did you mean {close[0]!r}?)' if close else ''
            raise AeropendError(f'{path}: the profile maps {quantity} to column {spec!r}, which the log does not '
                                f'have{hint}; its columns: {", ".join(header)}')
        index = header.index(str(spec))
    return [row[index].strip() for row in body]


def _numbers(values: list[str], quantity: str, path: Path) -> np.ndarray:
    out = np.empty(len(values))
    for i, value in enumerate(values):
        try:
            out[i] = float(value) if value else np.nan
        except ValueError:
            raise AeropendError(f'{path}: {quantity} in data row {i + 1} is {value!r}, not a number') from None
    return out


def _times(values: list[str], clock: dict, path: Path) -> np.ndarray:
    kind = clock.get('kind', 'seconds')
    if TIME_KINDS[kind] is not None:
        return _numbers(values, 'time', path) * TIME_KINDS[kind]
    fmt = clock.get('format')
    out = np.empty(len(values))
    first = None
    for i, value in enumerate(values):
        try:
            stamp = _dt.datetime.strptime(value, fmt) if fmt else _dt.datetime.fromisoformat(value)
        except ValueError:
            try:
                from dateutil import parser as date_parser
                stamp = date_parser.parse(value)
            except (ValueError, OverflowError):
                raise AeropendError(f'{path}: time stamp {value!r} in data row {i + 1} is not a date-time; give '
                                    'clock.format (strptime codes, e.g. "%d/%m/%Y %H:%M:%S.%f")') from None
        if stamp.tzinfo is not None:
            stamp = stamp.astimezone(_dt.timezone.utc).replace(tzinfo=None)
        first = first or stamp
        out[i] = (stamp - first).total_seconds()
    return out


def import_log(path: str | Path, profile: dict, profile_source: str = '') -> tuple[dict[str, np.ndarray], dict]:
    """Read a foreign log through a profile.

    Parameters
    ----------
    path : str or Path [-]
        The log.
    profile : dict [-]
        A checked profile (:func:`load_profile`).
    profile_source : str [-]
        Where the profile came from, for the metadata.

    Returns
    -------
    columns : dict of str -> ndarray, shape (n,) [SI]
        ``t`` [s] from 0, then the mapped quantities (and ``armature_voltage`` from the duty when not logged).
    metadata : dict [-]
        ``source_file``, ``source_sha256``, ``profile``, ``profile_file``, ``sample_rate_hz``, ``notes`` (one
        sentence per thing done: conversions, the clock, Va from the duty).

    Raises
    ------
    AeropendError
        A missing column, a non-number, unusable stamps (with the cause and the fix).
    """
    from aeropend_core.io.inputs import check_input
    path = Path(path)
    if not path.exists():
        raise AeropendError(f'no such file: {path}')
    check_input(path, 'the log', folder=profile.get('format', 'csv') == 'bag')     # a FIFO or device: refused
    check_profile(profile, profile_source or 'profile')
    notes: list[str] = []
    if profile.get('format', 'csv') == 'bag':
        from aeropend_core.io.recording import _load_bag
        recording = _load_bag(path)
        columns = {'t': recording.time - recording.time[0], **recording.signals}
        rate = 1.0 / float(np.median(np.diff(recording.time)))
    else:
        header, body = _read_table(path, profile.get('delimiter'))
        columns, rate = {}, None
        for quantity, entry in profile['columns'].items():
            raw = _numbers(_column(header, body, entry['column'], quantity, path), quantity, path)
            if 'unit' in entry:
                factor = unit_factor(quantity, entry, profile_source or 'profile')
                offset = -float(entry.get('zero', 0.0)) * factor if str(entry['unit']).startswith('count') else 0.0
                notes.append(f'{quantity} from column {entry["column"]!r} in {entry["unit"]} (x {factor:.6g}'
                             + (f', zero at {entry.get("zero", 0)} counts)' if offset else ')'))
            else:
                factor, offset = float(entry.get('scale', 1.0)), float(entry.get('offset', 0.0))
                notes.append(f'{quantity} from column {entry["column"]!r} as raw x {factor:.6g} + {offset:.6g}')
            values = raw * factor + offset
            if quantity == 'angle' and entry.get('wrap'):
                good = np.isfinite(values)
                values[good] = np.unwrap(values[good])
                turns = np.round(np.median(values[good]) / (2 * math.pi))
                values -= turns * 2 * math.pi
                notes.append('angle unwrapped across whole turns')
            columns[quantity] = values
        clock = profile.get('clock') or {}
        rate = clock.get('rate')
        n = len(body)
        if 'column' in clock:
            time = _times(_column(header, body, clock['column'], 'time', path), clock, path)
            from aeropend_core.signals.host_clock import (ClockContradiction, looks_host_buffered, regularise,
                                                          resolution_of)
            if clock.get('source') == 'host' or looks_host_buffered(time):
                try:
                    regular = regularise(time, rate, resolution_of(time))
                except ClockContradiction as error:
                    raise AeropendError(f'{path}: {error}') from None
                time = regular.time - regular.time[0]
                rate = 1.0 / regular.period
                notes.append(regular.describe())
            else:
                time = time - time[0]
                if n > 1 and time[-1] > 0:   # the device's stamps say its rate: end to end (a millis() column
                    rate = (n - 1) / float(time[-1])  # steps 22 and 23 ms at 44.5 Hz; its median would be 45.5 Hz)
        else:
            time = np.arange(n) / float(rate)
            notes.append(f'time from the sample order at {rate:.6g} Hz (the log has no time column)')
        columns = {'t': time, **columns}
    if 'armature_voltage' not in columns and 'duty' in columns:
        from aeropend_core.model.parameters import DEFAULT_PARAMETERS
        columns['armature_voltage'] = np.asarray(DEFAULT_PARAMETERS.voltage_from_duty(np.clip(columns['duty'], 0, 1)),
                                                 dtype=float)
        notes.append('armature_voltage computed from the duty by eq (8) (the log has no Va); the rig\'s supply and '
                     'drive are assumed to be the paper\'s')
    metadata = {'source_file': str(path), 'source_sha256': sha256_of(path), 'profile_file': profile_source,
                'profile': profile, 'sample_rate_hz': None if rate is None else float(rate), 'notes': notes}
    return columns, metadata


def write_imported(target: str, columns: dict[str, np.ndarray], metadata: dict) -> None:
    """Write an imported log in our CSV format (`target` a path, or '-' for standard output), its metadata as a first
    comment line (``# aeropend-import: {json}``, which :func:`aeropend_core.io.recording.load_csv` skips and
    :func:`read_import_metadata` reads)."""
    from aeropend_core.io.paths import write_atomically
    order = ['t'] + [k for k in ('duty', 'armature_voltage', 'armature_current', 'angle') if k in columns]
    lines = ['# aeropend-import: ' + json.dumps(metadata, sort_keys=True, default=str), ','.join(order)]
    table = np.column_stack([columns[k] for k in order])
    lines += [','.join(f'{v:.10g}' if np.isfinite(v) else '' for v in row) for row in table]
    text = '\n'.join(lines) + '\n'
    if target == '-':                                   # standard output
        sys.stdout.write(text)
        sys.stdout.flush()
        return
    write_atomically(target, lambda handle: handle.write(text))


def read_import_metadata(path: str | Path) -> dict | None:
    """The ``# aeropend-import:`` metadata of an imported CSV (None when the file has none)."""
    try:
        with open(path, encoding='utf-8-sig') as handle:
            first = handle.readline()
    except (OSError, UnicodeDecodeError):
        return None
    if first.startswith('# aeropend-import: '):
        try:
            return json.loads(first[len('# aeropend-import: '):])
        except (json.JSONDecodeError, RecursionError):      # nested too deep: not our metadata
            return None
    return None


__all__ = ['load_profile', 'check_profile', 'import_log', 'write_imported', 'read_import_metadata', 'sha256_of',
           'unit_factor', 'QUANTITIES']

"""Recognise a log that is not in aeropend's own CSV format, and guess a log profile for it from its header.

aeropend's CSV has the header ``t,duty,armature_voltage,armature_current,angle`` (SI, comma-separated, numbers
only). Another rig's log has its own column names, a ``;`` or tab between fields, PC date-times or ``millis()``,
counts instead of SI. :func:`foreign_log_error` turns the reader's complaint about such a file ("could not convert
string to float", "not comma-separated", "lacks required columns") into one message that says the file is another
rig's log and names the next step: ``aeropend import LOG --guess-profile PROFILE.yaml`` writes the profile
:func:`guess_profile` reads from the header and the first rows (delimiter, time column and its format, which column
is which quantity), then ``aeropend diagnose LOG --profile PROFILE.yaml`` reads the log directly.

A guess is a start, not a calibration: the units of counts (ADC, encoder zero) are known only to the wiring, and
every guessed entry says in a comment what to check.
"""
from __future__ import annotations

import csv
import datetime as _dt
import re
from pathlib import Path

from aeropend_core.errors import AeropendError

#: Header words (lower case, matched as whole words or prefixes of the column name) -> the quantity they suggest.
QUANTITY_WORDS = {
    'angle': ('angle', 'theta', 'enc', 'encoder', 'pos', 'position', 'as5040', 'phi'),
    'duty': ('pwm', 'duty', 'ocr', 'dc', 'u'),
    'armature_current': ('current', 'curr', 'ia', 'i_a', 'a0', 'amps', 'amp', 'i'),
    'armature_voltage': ('va', 'volt', 'voltage', 'v_a', 'vmotor', 'v'),
}
#: Header words of a time column, and the clock kind a name implies when its values are plain numbers.
TIME_WORDS = ('time', 't', 'timestamp', 'stamp', 'pc_time', 'date', 'datetime', 'millis', 'ms', 'micros', 'us',
              'seconds', 's', 'clock')
#: A unit word in a column's name -> the unit (pint spelling), and which quantity may carry it.
HEADER_UNITS = {'deg': 'deg', 'degree': 'deg', 'degrees': 'deg', 'rad': 'rad', 'pct': 'percent', 'percent': 'percent',
                'ma': 'mA', 'mv': 'mV'}
UNIT_OF_QUANTITY = {('angle', 'deg'), ('angle', 'rad'), ('duty', 'percent'), ('armature_current', 'mA'),
                    ('armature_voltage', 'mV')}
#: Lines read to guess (the header and the first rows are enough).
GUESS_LINES = 50


def _words(name: str) -> list[str]:
    return [w for w in re.split(r'[^a-z0-9]+', name.lower()) if w]


def _matches(name: str, words) -> bool:
    parts = _words(name)
    return any(part == word or (len(word) > 2 and part.startswith(word)) for part in parts for word in words)


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _datetime_format(value: str) -> str | None:
    """'iso' when `value` is an ISO 8601 date-time, a strptime format for a few common others, None otherwise."""
    try:
        _dt.datetime.fromisoformat(value)
        return 'iso'
    except ValueError:
        pass
    for fmt in ('%d/%m/%Y %H:%M:%S.%f', '%d/%m/%Y %H:%M:%S', '%m/%d/%Y %H:%M:%S.%f', '%H:%M:%S.%f', '%H:%M:%S',
                '%d.%m.%Y %H:%M:%S.%f', '%d.%m.%Y %H:%M:%S'):
        try:
            _dt.datetime.strptime(value, fmt)
            return fmt
        except ValueError:
            continue
    return None


def read_head(path: str | Path, lines: int = GUESS_LINES) -> list[str]:
    """The first non-blank, non-comment lines of a text file (at most `lines`); [] when it cannot be read or is
    not UTF-8 text."""
    head: list[str] = []
    try:
        with open(path, encoding='utf-8-sig') as handle:
            for line in handle:
                if line.strip() and not line.lstrip().startswith('#'):
                    head.append(line.rstrip('\r\n'))
                    if len(head) >= lines:
                        break
    except (OSError, UnicodeDecodeError):
        return []
    return head


def sniff_delimiter(header_line: str) -> str:
    """The field delimiter of a log's header line: ',', ';', a tab or a space (',' when none stands out)."""
    try:
        return csv.Sniffer().sniff(header_line, delimiters=',;\t ').delimiter
    except csv.Error:
        return ','


def guess_profile(path: str | Path) -> tuple[dict, list[str]]:
    """A log profile guessed from a log's header and first rows, and one sentence per guess to check.

    Parameters
    ----------
    path : str or Path [-]
        A CSV log written by another rig.

    Returns
    -------
    profile : dict [-]
        A profile :func:`aeropend_core.io.log_profile.check_profile` accepts (``delimiter``, ``clock``,
        ``columns``); the units of counts are placeholders to check.
    guesses : list of str [-]
        What was guessed and what to check, one sentence each.

    Raises
    ------
    AeropendError
        No header and data rows, or no column that can be the angle.
    """
    head = read_head(path)
    if len(head) < 2:
        raise AeropendError(f'{path}: no header and data rows to guess a profile from')
    delimiter = sniff_delimiter(head[0])
    rows = list(csv.reader(head, delimiter=delimiter))
    header = [h.strip() for h in rows[0]]
    body = [[cell.strip() for cell in row] for row in rows[1:] if len(row) == len(header)]
    if not body:
        raise AeropendError(f'{path}: no data row has as many fields as its header ({len(header)})')
    guesses = [f'delimiter {delimiter!r} (from the header line)']
    profile: dict = {'name': f'guessed from the header of {Path(path).name}: CHECK every unit', 'format': 'csv',
                     'delimiter': delimiter}
    columns: dict[str, dict] = {}
    clock: dict = {}
    used: set[str] = set()
    for name in header:                              # the time column: by its name, else by date-time values
        values = [row[header.index(name)] for row in body]
        stamp_format = _datetime_format(values[0]) if values[0] and not _is_number(values[0]) else None
        if stamp_format or (_matches(name, TIME_WORDS) and all(_is_number(v) for v in values if v)):
            clock['column'] = name
            used.add(name)
            if stamp_format:
                clock.update({'kind': 'datetime', 'source': 'host'})
                if stamp_format != 'iso':
                    clock['format'] = stamp_format
                written = 'ISO 8601' if stamp_format == 'iso' else stamp_format
                guesses.append(f'time from column {name!r} as date-times ({written}) stamped by a PC (clock.source '
                               'host: regularised from the line order)')
            else:
                kind = 'milliseconds' if _matches(name, ('millis', 'ms')) else \
                    'microseconds' if _matches(name, ('micros', 'us')) else 'seconds'
                clock.update({'kind': kind, 'source': 'device'})
                guesses.append(f'time from column {name!r} in {kind} of the logger\'s own clock')
            break
    for quantity, words in QUANTITY_WORDS.items():
        for name in header:
            if name in used or not _matches(name, words):
                continue
            values = [float(row[header.index(name)]) for row in body if _is_number(row[header.index(name)])]
            if not values:
                continue
            columns[quantity] = _entry(quantity, name, values, guesses)
            used.add(name)
            break
    if 'angle' not in columns:
        raise AeropendError(f'{path}: no column of its header ({", ".join(header)}) reads as the angle; write the '
                            'profile by hand (docs/log-import.md)')
    if not clock:
        clock['rate'] = 490.0
        guesses.append('no time column: the line rate is a placeholder (clock.rate 490 Hz); give the logger\'s rate')
    profile['clock'] = clock
    profile['columns'] = columns
    return profile, guesses


def _entry(quantity: str, name: str, values: list[float], guesses: list[str]) -> dict:
    """The profile entry of one column, its unit guessed from the range of its values; the guess said."""
    low, high = min(values), max(values)
    integers = all(float(v).is_integer() for v in values)
    said = next((unit for word, unit in HEADER_UNITS.items() if _matches(name, (word,)) and
                 (quantity, unit) in UNIT_OF_QUANTITY), None)
    if said is not None:                              # the header names its unit: taken as written
        guesses.append(f'{quantity} from column {name!r} in {said} (its header says so)')
        return {'column': name, 'unit': said}
    if quantity == 'duty':
        if high > 100.5 or (integers and high > 1.0 and _matches(name, ('pwm', 'ocr'))):
            guesses.append(f'duty from column {name!r} as an 8-bit register 0..255 (scale 1/255): CHECK the timer\'s '
                           'top value')
            return {'column': name, 'scale': 1.0 / 255.0}
        if high > 1.0:
            guesses.append(f'duty from column {name!r} in percent')
            return {'column': name, 'unit': 'percent'}
        guesses.append(f'duty from column {name!r} as a fraction 0..1')
        return {'column': name, 'scale': 1.0}
    if quantity == 'angle':
        if integers and 0 <= low and high < 4096 and high > 7:
            turn = 1024 if high < 1024 else 4096
            guesses.append(f'angle from column {name!r} in encoder counts, {turn} per turn, zero at 0 counts, wrapped: '
                           'CHECK counts_per_turn and zero (the reading with the rod hanging still)')
            return {'column': name, 'unit': 'count', 'counts_per_turn': turn, 'zero': 0, 'wrap': True}
        if max(abs(low), abs(high)) > 2 * 3.1416:
            guesses.append(f'angle from column {name!r} in degrees')
            return {'column': name, 'unit': 'deg'}
        guesses.append(f'angle from column {name!r} in radians')
        return {'column': name, 'unit': 'rad'}
    if quantity == 'armature_current':
        if integers and high > 20:
            guesses.append(f'armature_current from column {name!r} as ADC counts: scale 1.0 A per count is a '
                           'PLACEHOLDER; give the amperes per count of your sense resistor and amplifier '
                           '(a wrong scale makes the armature resistance wrong by the same factor)')
            return {'column': name, 'scale': 1.0, 'offset': 0.0}
        unit = 'mA' if high > 20 else 'A'
        guesses.append(f'armature_current from column {name!r} in {unit} (from the size of its values): CHECK')
        return {'column': name, 'unit': unit}
    unit = 'mV' if high > 100 else 'V'
    guesses.append(f'armature_voltage from column {name!r} in {unit} (from the size of its values): CHECK')
    return {'column': name, 'unit': unit}


def profile_yaml(profile: dict, guesses: list[str], source: str) -> str:
    """The text of a guessed profile: a comment naming the log and every guess, then the YAML."""
    import yaml
    lines = [f'# Log profile guessed by `aeropend import {source} --guess-profile` from the header and first rows.',
             '# Check each guess below against your logger and wiring before trusting any number (docs/log-import.md):']
    lines += [f'#  - {guess}' for guess in guesses]
    return '\n'.join(lines) + '\n' + yaml.safe_dump(profile, sort_keys=False, default_flow_style=None)


def looks_foreign(path: str | Path) -> bool:
    """True when a CSV's header is not aeropend's own: no ``t`` (or ``time``) and ``angle`` columns, or its fields
    are not separated by commas."""
    head = read_head(path, 2)
    if not head:
        return False
    fields = [f.strip().lower() for f in head[0].split(',')]
    names = {re.sub(r'\s*[\[(].*$', '', f) for f in fields}
    return len(fields) == 1 or not ({'t', 'time'} & names and {'angle', 'theta'} & names)


def foreign_log_error(path: str | Path, problem: str) -> AeropendError:
    """The error for a log that is not in our CSV format: it says so, why (`problem`), and the next step, with the
    profile guessed from its header when one can be (the guess's delimiter, time column and angle column named)."""
    stem = Path(path).with_suffix('').name or 'rig_log'
    target = str(Path(path).with_name(f'{stem}_profile.yaml'))
    try:
        profile, _ = guess_profile(path)
    except (AeropendError, ValueError, IndexError):
        profile = None
    if profile is None:
        lead = (f'Write a log profile for it (docs/log-import.md; shipped ones in config/profiles/), then '
                f'`aeropend import {path} --profile PROFILE.yaml -o run.csv`, or read it directly with '
                f'--profile PROFILE.yaml')
    else:
        clock = profile['clock']
        time = (f"time {clock['column']!r} as {clock['kind']}" if 'column' in clock else 'no time column')
        found = ', '.join(f"{q} {e['column']!r}" for q, e in profile['columns'].items())
        lead = (f'A profile guessed from its header (delimiter {profile["delimiter"]!r}, {time}, {found}): '
                f'`aeropend import {path} --guess-profile {target}` writes it; check its units, then read the log '
                f'with --profile {target} (or `aeropend import {path} --profile {target} -o run.csv`); '
                'docs/log-import.md')
    return AeropendError(f'{path} is not in aeropend\'s own CSV format ({problem}); it looks like another rig\'s '
                         f'log: bring it in through a log profile. {lead}')


__all__ = ['foreign_log_error', 'guess_profile', 'looks_foreign', 'profile_yaml', 'read_head', 'sniff_delimiter']

"""Load a recording of the rig (CSV, or MCAP bags via :mod:`aeropend_core.io.bag`) into plain arrays.

A :class:`Recording` is a time vector and named signals, SI units, time-first arrays of shape ``(n_samples,)``:
``duty`` [1], ``armature_voltage`` [V], ``armature_current`` [A], ``angle`` [rad], plus any truth columns a
simulation wrote (``true_motor_speed`` [rad/s], ``true_angular_rate`` [rad/s], ...). Measured columns win over
truth columns of the same quantity: :meth:`Recording.signal` looks up ``name`` then ``true_<name>``.
"""
from __future__ import annotations

import csv
import sys
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from aeropend_core.errors import AeropendError
from aeropend_core.io.samples import INPUT_COLUMNS, REQUIRED_COLUMNS, Recording
from aeropend_core.io.paths import write_atomically
from aeropend_core.model.parameters import SAMPLE_TIME

def from_columns(columns: Mapping[str, np.ndarray], source: str = '', findings: tuple = ()) -> Recording:
    """A :class:`Recording` from a mapping with a ``t`` column (e.g. ``Trajectory.columns()``).

    Parameters
    ----------
    columns : mapping of str -> ndarray, shape (n,) [SI unit of each column]
        ``t`` [s], ``angle`` [rad] and ``armature_voltage`` [V] or ``duty`` [1] at least (``armature_current`` [A]
        for the full model); any other column is kept as a signal.
    source : str [-]
        Where the data came from, for messages.
    findings : tuple of Finding [-]
        Data-quality findings already made about these columns (by a reader), kept with the recording.

    Returns
    -------
    Recording
        The columns as float arrays (``t`` becomes ``time``).

    Raises
    ------
    AeropendError
        A required column is missing, or a column's length differs from ``t``.

    Examples
    --------
    >>> import numpy as np
    >>> from aeropend_core import AeropendError, from_columns
    >>> time = np.arange(0.0, 1.0, 0.002)                                                        # s
    >>> float(from_columns({'t': time, 'duty': np.full(time.size, 0.5), 'angle': 0.1 * time}).signal('angle')[-1])
    0.0998
    >>> try:
    ...     from_columns({'t': time, 'duty': np.full(time.size, 0.5)})                            # no angle
    ... except AeropendError as error:
    ...     'angle' in str(error)
    True
    """
    missing = [c for c in REQUIRED_COLUMNS if c not in columns]
    if not any(c in columns for c in INPUT_COLUMNS):
        missing.append(' or '.join(INPUT_COLUMNS))
    if missing:
        raise AeropendError(f'{source or "data"} lacks required column(s) {missing}; need '
                            + ', '.join(f'{k} [{u}]' for k, u in REQUIRED_COLUMNS.items()) + ' and '
                            + ' or '.join(f'{k} [{u}]' for k, u in INPUT_COLUMNS.items())
                            + ' (armature_current [A] too, for the full model)')
    time = np.asarray(columns['t'], dtype=float)
    signals = {k: np.asarray(v, dtype=float) for k, v in columns.items() if k != 't'}
    for k, v in signals.items():
        if v.shape != time.shape:
            raise AeropendError(f'{source or "data"}: column {k!r} has {v.shape} samples, t has {time.shape}')
    return Recording(time, signals, source, tuple(findings))


#: Other spellings of the column names (lower case) -> the name used here.
COLUMN_ALIASES = {'time': 't', 'theta': 'angle', 'voltage': 'armature_voltage', 'current': 'armature_current',
                  'va': 'armature_voltage', 'ia': 'armature_current'}
#: (column, unit written in its header) -> (factor to SI, finding code). SI units are accepted as they are.
UNIT_CONVERSIONS = {('t', 'ms'): (1e-3, 'time_in_milliseconds'), ('angle', 'deg'): (np.pi / 180, 'angle_in_degrees'),
                    ('angle', 'degree'): (np.pi / 180, 'angle_in_degrees'),
                    ('angle', 'degrees'): (np.pi / 180, 'angle_in_degrees'),
                    ('armature_current', 'ma'): (1e-3, 'current_in_milliamps'),
                    ('armature_voltage', 'mv'): (1e-3, 'voltage_in_millivolts'),
                    ('duty', '%'): (1e-2, 'duty_in_percent')}
SI_UNITS = {'t': 's', 'angle': 'rad', 'armature_current': 'a', 'armature_voltage': 'v', 'duty': '1'}


def _normalise_header(header: list[str], path: Path) -> tuple[list[str], dict[int, float], list]:
    """Column names as used here (``Angle [deg]`` -> ``angle``, scaled to rad), the factor of each converted
    column, and one finding per change (nothing renamed or converted silently)."""
    import re

    from aeropend_core.signals.quality import DataQualityError, Finding
    names, scales, findings, renamed = [], {}, [], []
    for index, raw in enumerate(header):
        match = re.fullmatch(r'\s*([^\[\(]*?)\s*[\[\(]\s*([^\]\)]*?)\s*[\]\)]\s*', raw)
        name, unit = (match.group(1), match.group(2)) if match else (raw.strip(), '')
        key = name.strip().lower().replace(' ', '_')
        key = COLUMN_ALIASES.get(key, key)
        if key not in SI_UNITS and key != 'sequence' and not key.startswith('true_'):
            key = name.strip()              # not ours: keep it as written
        unit_key = unit.strip().lower()
        if unit_key and key in SI_UNITS and unit_key not in (SI_UNITS[key], '-', ''):
            if (key, unit_key) not in UNIT_CONVERSIONS:
                raise DataQualityError(Finding('unknown_unit', 'refused', f'{path}: column {index + 1} {raw!r}: unit '
                                               f'{unit!r} is not known for {key}; write it in {SI_UNITS[key]}'))
            factor, code = UNIT_CONVERSIONS[(key, unit_key)]
            scales[index] = factor
            findings.append(Finding(code, 'repaired', f'{path}: column {raw!r} is in {unit} by its header; converted '
                                    f'to {SI_UNITS[key].replace("a", "A").replace("v", "V")} (x {factor:.6g})'))
        if key != raw:
            renamed.append(f'{raw!r} -> {key!r}')
        names.append(key)
    if renamed:
        findings.insert(0, Finding('column_names', 'repaired', f'{path}: column names read as ' + ', '.join(renamed)))
    return names, scales, findings


def load_csv(path: str | Path) -> Recording:
    """Read a CSV with a header row (``t,duty,armature_voltage,armature_current,angle[,true_...]``)."""
    from aeropend_core.io.inputs import open_input
    from aeropend_core.signals.quality import DataQualityError, Finding
    path = Path(path)
    findings = []
    try:
        with open_input(path, 'the recording') as raw:        # a FIFO or device: refused, never waited on
            bom = raw.read(3) == b'\xef\xbb\xbf'
        with open_input(path, 'the recording', text=True, newline='', encoding='utf-8-sig') as handle:
            reader = csv.reader(_bounded_lines(handle, path))
            header = [h.strip() for h in next(reader, [])]
            while header and header[0].startswith('#'):      # `aeropend import` metadata: a leading comment
                header = [h.strip() for h in next(reader, [])]
            table, ragged, non_numeric = _read_rows(reader, len(header))
    except OSError as error:    # permissions: exit 1 (the system refused), see aeropend_core.cli
        from aeropend_core.io.paths import storage_error
        raise storage_error(error, f'cannot read {path}: {error.strerror or error}') from None
    except (UnicodeDecodeError, csv.Error) as error:
        raise AeropendError(f'{path} is not a text CSV file ({error}); expected a header t,duty,armature_voltage,... '
                            'and comma-separated numbers') from None
    if not header:
        raise AeropendError(f'{path} is empty; expected a CSV header t,duty,armature_voltage,...')
    if bom:
        findings.append(Finding('byte_order_mark', 'repaired', f'{path}: starts with a UTF-8 byte-order mark (as Excel '
                                'writes); skipped'))
    written = list(header)
    header, scales, notes = _normalise_header(header, path)
    findings.extend(notes)
    seen: dict[str, int] = {}
    for index, name in enumerate(header):
        if name in seen:
            raise DataQualityError(Finding(
                'duplicate_column', 'refused', f'{path}: columns {seen[name] + 1} and {index + 1} '
                f'({written[seen[name]]!r}, {written[index]!r}) are both named {name!r}; which one holds the data '
                'cannot be told: delete or rename one', count=2), findings)
        seen[name] = index
    from aeropend_core.io.profile_guess import foreign_log_error, looks_foreign
    if len(header) == 1 and any(sep in header[0] for sep in ';\t'):
        separator = 'semicolons' if ';' in header[0] else 'tabs'
        raise foreign_log_error(path, f'its header {header[0]!r} is separated by {separator}, not commas')
    if ragged is not None:
        row_number, fields = ragged
        raise AeropendError(f'{path}: data row {row_number} has {fields} fields, the header has '
                            f'{len(header)}; is the file cut short or edited by hand?')
    if non_numeric is not None:
        if looks_foreign(path):         # a PC date-time under another rig's header: not a typo in our format
            raise foreign_log_error(path, f'non-numeric value ({non_numeric}) under the header {", ".join(written)}')
        raise AeropendError(f'{path}: non-numeric value ({non_numeric}); expected numbers under the header') from None
    if table.size == 0:
        raise AeropendError(f'{path} has a header but no samples')
    if table.ndim != 2 or table.shape[1] != len(header):
        raise AeropendError(f'{path}: rows have a different number of fields than the header ({len(header)})')
    for index, factor in scales.items():
        table[:, index] *= factor
    lacking = [name for name in REQUIRED_COLUMNS if name not in header]
    if lacking or not any(name in header for name in INPUT_COLUMNS):
        raise foreign_log_error(path, f'no column named {" or ".join(lacking or INPUT_COLUMNS)}; its columns: '
                                f'{", ".join(written)}')
    return from_columns({name: table[:, i] for i, name in enumerate(header)}, source=str(path),
                        findings=tuple(findings))


#: Longest CSV line read [characters]: a row of this format is ~100 characters, a header with every column a few
#: hundred. A longer line (a 1 GB file without line breaks) is refused before it is held in memory.
MAX_CSV_LINE = 1 << 16


def _bounded_lines(handle, path: Path):
    """The lines of `handle`, refusing one longer than :data:`MAX_CSV_LINE` after reading only that much of it."""
    number = 0
    while True:
        line = handle.readline(MAX_CSV_LINE + 1)
        if not line:
            return
        number += 1
        if len(line) > MAX_CSV_LINE:
            raise AeropendError(f'{path}: line {number} is longer than {MAX_CSV_LINE} characters (a row of a '
                                'recording is about 100); is this a CSV with one sample per line? (line breaks '
                                'lost, or not a recording)')
        yield line


#: Rows converted to floats at once while reading a CSV (a long record is never held as text: 64 Ki rows of
#: strings take ~25 MB, a 1-hour record's 1.8 M rows would take ~1.4 GB).
CSV_BLOCK_ROWS = 65536


def _read_rows(reader, width: int) -> tuple[np.ndarray, tuple[int, int] | None, str | None]:
    """The non-blank rows of `reader` as a float table (empty cells NaN), converted block by block.

    Returns the table, the first ragged row as (1-based data row number, fields) or None, and the first
    non-numeric value's error text (with its data row number) or None. Reading stops at the first ragged row and
    at the end of the block that holds the first non-numeric value; the first block is converted after its first
    row, so a text row at the top is refused at once.
    """
    blocks: list[np.ndarray] = []
    block: list[list[str]] = []
    ragged, non_numeric, number = None, None, 0

    def convert() -> None:
        nonlocal non_numeric
        first = number - len(block) + 1              # data row number of block[0]
        if block and non_numeric is None:
            try:
                try:        # numpy parses each cell as float() does, in C; an empty cell (NaN) takes the loop below
                    converted = np.array(block, dtype=float)
                except ValueError:
                    converted = np.array([[float(cell) if cell.strip() else np.nan for cell in row] for row in block],
                                         dtype=float)
                blocks.append(converted.reshape(len(block), width))
            except ValueError as error:
                non_numeric = str(error)
                for offset, row in enumerate(block):
                    try:
                        [float(cell) for cell in row if cell.strip()]
                    except ValueError:
                        non_numeric = f'{error}, data row {first + offset}'
                        break
        block.clear()

    for row in reader:
        if not row or not (row[0].strip() or any(cell.strip() for cell in row)):      # blank: skipped
            continue
        number += 1
        if len(row) != width:
            ragged = (number, len(row))
            break
        block.append(row)
        if number == 1 or len(block) >= CSV_BLOCK_ROWS:
            convert()
            if non_numeric is not None:
                break
    convert()
    table = np.concatenate(blocks) if blocks else np.zeros((0, width))
    return table, ragged, non_numeric


def load_recording(path: str | Path, sample_time: float | None = SAMPLE_TIME) -> Recording:
    """Load a recording by file type: ``.csv``, or an MCAP bag (``.mcap`` file or bag folder, its
    ``/aeropend/samples``; a file cut short by a killed recorder is read up to its last complete chunk), and pass it
    through the data-quality gate (:func:`aeropend_core.signals.quality.check_recording`).

    Parameters
    ----------
    path : str or Path [-]
        A ``.csv`` file, an ``.mcap`` file or a bag folder.
    sample_time : float or None [s]
        The declared sample time (the rig's 1/490 s); None: the stamps are checked against themselves only.

    Returns
    -------
    Recording
        The repaired recording, time [s] and the signals in SI units; its ``findings`` say every repair and warning.

    Raises
    ------
    AeropendError
        Unreadable files, and data the gate refuses (:class:`~aeropend_core.signals.quality.DataQualityError`).

    Examples
    --------
    >>> import tempfile
    >>> from pathlib import Path
    >>> import numpy as np
    >>> from aeropend_core import load_recording, simulate
    >>> from aeropend_core.io.recording import write_csv
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     write_csv(str(Path(folder) / 'run.csv'), simulate(np.full(980, 0.5), seed=1).columns(with_truth=False))
    ...     recording = load_recording(Path(folder) / 'run.csv')
    >>> len(recording), 'armature_current' in recording.signals                    # samples at 490 Hz
    (980, True)
    """
    from aeropend_core.signals.quality import check_recording
    path = Path(path)
    if not path.exists():
        from aeropend_core.io.paths import path_problem
        problem = path_problem(path)        # a symbolic link loop or a dangling link is named as such
        raise AeropendError(f'no such file or folder: {path}' if problem == 'does not exist' else f'{path} {problem}')
    from aeropend_core.io.inputs import check_input
    check_input(path, 'the recording', folder=True)     # a FIFO, device or socket would block or never end
    if path.is_dir():
        check_bag_folder(path)                          # `diagnose bags/`: a folder of bags is not one bag
    if path.suffix.lower() == '.csv':
        recording = load_csv(path)
    elif path.suffix.lower() == '.mcap' or path.is_dir():
        recording = _load_bag(path)
    else:
        from aeropend_core.io.profile_guess import foreign_log_error, read_head
        head = read_head(path, 2)
        if len(head) == 2 and any(sep in head[0] for sep in ',;\t'):     # a text log with a header: another rig's
            raise foreign_log_error(path, f'a {path.suffix or "suffix-less"} file, where our records are .csv or MCAP')
        raise AeropendError(f'{path}: unknown recording type {path.suffix!r}; give a .csv (or an MCAP bag)')
    return check_recording(recording, sample_time=sample_time).recording


def check_bag_folder(path: str | Path) -> None:
    """Refuse a folder that is not one bag (no ``.mcap`` file, no ``metadata.yaml``) with a lead: the bags and
    CSV records it holds, newest first, and the command for the newest (``aeropend diagnose bags/`` said nothing
    useful before).

    Raises
    ------
    AeropendError
        `path` holds no bag of its own (exit status 2).
    """
    path = Path(path)
    if (path / 'metadata.yaml').is_file() or any(path.glob('*.mcap')):
        return
    try:
        inside = list(path.iterdir())
    except OSError:
        return                                          # unreadable: the bag reader says why
    bags = [p for p in inside if p.is_dir() and ((p / 'metadata.yaml').is_file() or any(p.glob('*.mcap')))]
    records = sorted(bags + [p for p in inside if p.suffix.lower() in ('.csv', '.mcap') and p.is_file()],
                     key=lambda p: p.stat().st_mtime, reverse=True)
    if not records:
        raise AeropendError(f'{path} is a folder but not a bag (no .mcap file, no metadata.yaml) and holds no bag or '
                            'CSV record; give a .csv, an .mcap file or a bag folder (`aeropend run` records them '
                            'under bags/)')
    listed = ', '.join(str(p) for p in records[:6]) + (f' and {len(records) - 6} more' if len(records) > 6 else '')
    raise AeropendError(f'{path} is a folder of {len(records)} records, not one bag; give one of them, e.g. the '
                        f'newest, {records[0]} (newest first: {listed})')


def _load_bag(path: Path) -> Recording:
    """The ``/aeropend/samples`` of an MCAP bag (folder or ``.mcap``), see :func:`aeropend_core.io.bag.read_samples`."""
    from aeropend_core.io.bag import read_samples
    damage: list = []
    samples = read_samples(path, on_incomplete='ignore', damage=damage)     # said once: as findings, below
    columns = {'t': samples['time']}
    # integer-nanosecond clocks (stamp_ns, receive_time_ns) do not survive float64; t already holds the stamps
    columns.update({k: v for k, v in samples.items() if k != 'time' and not k.endswith('_ns')})
    return from_columns(columns, source=str(path), findings=bag_findings(path, damage))


#: Finding code of each kind of bag damage (:class:`aeropend_core.io.mcap_scan.BagDamage`).
_BAG_CODES = {'chunk_skipped': 'bag_damaged', 'record_skipped': 'bag_damaged', 'unknown_channel': 'bag_damaged',
              'undecodable': 'bag_damaged', 'stamp_out_of_order': 'bag_damaged',
              'cut': 'bag_incomplete', 'no_crc': 'bag_no_crc', 'summary_mismatch': 'bag_summary_mismatch',
              'summary_damaged': 'bag_summary_damaged', 'no_footer': 'bag_summary_damaged'}


def bag_findings(path: str | Path, damage: list) -> tuple:
    """Findings for what reading a bag skipped or noticed (:class:`aeropend_core.io.bag.SampleDamage` list).

    A damaged chunk or a cut file is a ``warning`` naming the lost span [s] and sample count (``where``,
    ``count``); chunks without CRC, a summary that disagrees with the records or is damaged are warnings too;
    a duplicated chunk or a record read although its type byte or length was damaged is ``repaired``. So a bag
    read partially is never "clean".
    """
    from aeropend_core.io import bag_lock
    from aeropend_core.signals.quality import Finding
    findings = list(schedule_findings(path))
    writer = bag_lock.live_writer(path)
    live = writer is not None
    for item in damage:
        kind = item.damage.kind
        if kind == 'no_crc':
            findings.append(Finding('bag_no_crc', 'warning', f'{path}: this bag has no CRCs: bit flips cannot be '
                                    f'detected ({item.line()})'))
            continue
        code = _BAG_CODES.get(kind, 'bag_structure')
        severity = 'warning' if code != 'bag_structure' else 'repaired'
        advice = ''
        if item.damage.lost:
            advice = (f'; still being recorded by {writer.describe()}: read again once the recording ends'
                      if live and kind == 'cut'
                      else f'; the rest was read. aeropend bag-recover {path} writes a repaired copy')
        where = None
        if item.t_start is not None or item.t_stop is not None:
            where = (item.t_start if item.t_start is not None else item.t_stop,
                     item.t_stop if item.t_stop is not None else item.t_start)
        findings.append(Finding(code, severity, f'{path}: {item.line()}{advice}', where, item.samples or 0))
    return tuple(findings)


def schedule_findings(path: str | Path) -> tuple:
    """A ``schedule_incomplete`` warning for a bag whose run did not play its schedule whole (metadata.yaml's
    ``custom_data`` says ``aeropend.schedule_complete: 'false'``: the run was stopped, the rig or simulator went
    quiet, the excitation never finished), so that every later diagnosis of it says so (text, JSON, report).
    Empty for a whole run and for a bag that states nothing (recorded by another program)."""
    from aeropend_core.io.bag import bag_information
    from aeropend_core.signals.quality import Finding
    custom = bag_information(Path(path)).get('custom_data') or {}
    if not isinstance(custom, dict) or str(custom.get('aeropend.schedule_complete', '')).lower() != 'false':
        return ()
    planned = custom.get('aeropend.schedule_seconds')
    try:
        planned_text = f' of its {float(planned):.1f} s schedule' if planned is not None else ' of its schedule'
    except ValueError:
        planned_text = ' of its schedule'
    return (Finding('schedule_incomplete', 'warning', f'{path}: the run that recorded this bag was cut short: it '
                    f'did not play the whole{planned_text} (metadata.yaml: aeropend.schedule_complete false); '
                    'the record excites the rig less than planned, so an effect the missing part would have shown '
                    'can go unseen. Record a whole run (aeropend run) to be sure'),)


def write_csv(path: str, columns: dict[str, np.ndarray]) -> None:
    """Write equal-length columns as CSV with a header row (``-`` for standard output).

    Parameters
    ----------
    path : str [-]
        The file, or ``-`` for standard output.
    columns : dict of str -> ndarray, shape (n,) [SI unit of each column]
        ``t`` [s] first by convention, then the signals; written in this order.

    Returns
    -------
    None

    A file is written under a temporary name and renamed when complete, so a failure (disk full, no permission)
    never leaves a shorter file that reads as a valid recording; the error says what the system refused. A
    symbolic link is written through (its target replaced); devices and named pipes are refused.
    """
    table = np.column_stack(list(columns.values()))
    header = ','.join(columns)
    fmt = column_formats(columns)
    if path == '-':
        np.savetxt(sys.stdout, table, delimiter=',', header=header, comments='', fmt=fmt)
        return
    write_atomically(path, lambda handle: np.savetxt(handle, table, delimiter=',', header=header, comments='',
                                                     fmt=fmt), '--output', 'the CSV')


#: Significant digits of the measured and truth columns (float32-like: far below any sensor's resolution).
VALUE_FORMAT = '%.9g'
#: Time keeps 12 significant digits: 1 us up to 1e5 s, finer below ('%.9g' keeps only 0.1 ms at 1e5 s, 5 % of a
#: 490 Hz step, and the data-quality gate would then have to rebuild the grid).
TIME_FORMAT = '%.12g'


def column_formats(columns: dict[str, np.ndarray]) -> list[str]:
    """``np.savetxt`` formats: :data:`TIME_FORMAT` for the time column ``t``, :data:`VALUE_FORMAT` for the rest."""
    return [TIME_FORMAT if name == 't' else VALUE_FORMAT for name in columns]

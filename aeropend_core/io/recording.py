"""Load a recording of the rig (CSV, or MCAP bags via :mod:`aeropend_core.io.bag`) into plain arrays.

A :class:`Recording` is a time vector and named signals, SI units, time-first arrays of shape ``(n_samples,)``:
``duty`` [1], ``armature_voltage`` [V], ``armature_current`` [A], ``angle`` [rad], plus any truth columns a
simulation wrote (``true_motor_speed`` [rad/s], ``true_angular_rate`` [rad/s], ...). Measured columns win over
truth columns of the same quantity: :meth:`Recording.signal` looks up ``name`` then ``true_<name>``.
"""
from __future__ import annotations

import csv
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from aeropend_core.errors import AeropendError

#: Columns every recording must have (what the rig measures), with units.
REQUIRED_COLUMNS = {'t': 's', 'armature_voltage': 'V', 'armature_current': 'A', 'angle': 'rad'}


@dataclass(frozen=True, eq=False)
class Recording:
    """Samples of one record.

    Attributes
    ----------
    time : ndarray, shape (n,)
        Sample times [s].
    signals : dict of str -> ndarray, shape (n,)
        Every other column, SI units.
    source : str
        Where it came from (file path), for messages.
    """

    time: np.ndarray
    signals: dict[str, np.ndarray] = field(default_factory=dict)
    source: str = ''

    def __len__(self) -> int:
        return len(self.time)

    def has(self, name: str) -> bool:
        """True if ``name`` or ``true_<name>`` is present."""
        return name in self.signals or f'true_{name}' in self.signals

    def signal(self, name: str) -> np.ndarray:
        """The column ``name``, else ``true_<name>`` (simulator truth); AeropendError naming what exists."""
        for key in (name, f'true_{name}'):
            if key in self.signals:
                return self.signals[key]
        raise AeropendError(f'{self.source or "recording"} has no column {name!r} (nor true_{name}); '
                            f'columns: {", ".join(["t", *self.signals])}')

    def window(self, start: float, stop: float) -> Recording:
        """The samples with start <= t < stop [s]."""
        keep = (self.time >= start) & (self.time < stop)
        return Recording(self.time[keep], {k: v[keep] for k, v in self.signals.items()}, self.source)


def from_columns(columns: Mapping[str, np.ndarray], source: str = '') -> Recording:
    """A :class:`Recording` from a mapping with a ``t`` column (e.g. ``Trajectory.columns()``)."""
    missing = [c for c in REQUIRED_COLUMNS if c not in columns]
    if missing:
        raise AeropendError(f'{source or "data"} lacks required column(s) {missing}; need '
                            + ', '.join(f'{k} [{u}]' for k, u in REQUIRED_COLUMNS.items()))
    time = np.asarray(columns['t'], dtype=float)
    signals = {k: np.asarray(v, dtype=float) for k, v in columns.items() if k != 't'}
    for k, v in signals.items():
        if v.shape != time.shape:
            raise AeropendError(f'{source or "data"}: column {k!r} has {v.shape} samples, t has {time.shape}')
    return Recording(time, signals, source)


def load_csv(path: str | Path) -> Recording:
    """Read a CSV with a header row (``t,duty,armature_voltage,armature_current,angle[,true_...]``)."""
    path = Path(path)
    try:
        with path.open(newline='') as handle:
            reader = csv.reader(handle)
            header = [h.strip() for h in next(reader, [])]
            rows = [row for row in reader if row and any(cell.strip() for cell in row)]
    except OSError as error:    # permissions: exit 1 (the system refused), see aeropend_core.cli
        from aeropend_core.io.paths import storage_error
        raise storage_error(error, f'cannot read {path}: {error.strerror or error}') from None
    except (UnicodeDecodeError, csv.Error) as error:
        raise AeropendError(f'{path} is not a text CSV file ({error}); expected a header t,duty,armature_voltage,... '
                            'and comma-separated numbers') from None
    if not header:
        raise AeropendError(f'{path} is empty; expected a CSV header t,duty,armature_voltage,...')
    if len(header) == 1 and any(sep in header[0] for sep in ';\t'):
        raise AeropendError(f'{path}: the header {header[0]!r} is not comma-separated; write the fields separated '
                            'by commas')
    ragged = next((k for k, row in enumerate(rows) if len(row) != len(header)), None)
    if ragged is not None:
        raise AeropendError(f'{path}: data row {ragged + 1} has {len(rows[ragged])} fields, the header has '
                            f'{len(header)}; is the file cut short or edited by hand?')
    try:
        table = np.array([[float(cell) if cell.strip() else np.nan for cell in row] for row in rows], dtype=float)
    except ValueError as error:
        raise AeropendError(f'{path}: non-numeric value ({error}); expected numbers under the header') from None
    if table.size == 0:
        raise AeropendError(f'{path} has a header but no samples')
    if table.ndim != 2 or table.shape[1] != len(header):
        raise AeropendError(f'{path}: rows have a different number of fields than the header ({len(header)})')
    return from_columns({name: table[:, i] for i, name in enumerate(header)}, source=str(path))


def load_recording(path: str | Path) -> Recording:
    """Load a recording by file type: ``.csv``, or an MCAP bag (``.mcap`` file or bag folder, its
    ``/aeropend/samples``; a file cut short by a killed recorder is read up to its last complete chunk)."""
    path = Path(path)
    if not path.exists():
        from aeropend_core.io.paths import path_problem
        problem = path_problem(path)        # a symbolic link loop or a dangling link is named as such
        raise AeropendError(f'no such file or folder: {path}' if problem == 'does not exist' else f'{path} {problem}')
    if path.suffix.lower() == '.csv':
        return checked_time(load_csv(path))
    if path.suffix.lower() == '.mcap' or path.is_dir():
        return checked_time(_load_bag(path))
    raise AeropendError(f'{path}: unknown recording type {path.suffix!r}; give a .csv (or an MCAP bag)')


def checked_time(recording: Recording) -> Recording:
    """The recording with its time stamps checked: finite and strictly increasing.

    A sample repeated exactly (same time stamp and the same value in every column, e.g. a message recorded twice)
    is dropped, with a warning saying how many and where. Anything else that does not move forward in time (a
    stamp going back, or two different samples with the same stamp) is refused with the index of the first one:
    reordering or averaging them would be a guess.

    Raises
    ------
    AeropendError
        Non-finite stamps, or stamps that do not increase.
    """
    time, where = recording.time, recording.source or 'the recording'
    bad = np.flatnonzero(~np.isfinite(time))
    if bad.size:
        raise AeropendError(f'{where}: {bad.size} time stamp(s) are not finite numbers (first at sample {bad[0]}); '
                            'fix or remove those samples')
    if len(time) < 2:
        return recording
    step = np.diff(time)
    repeated = np.flatnonzero(step == 0) + 1
    if repeated.size:
        same = np.ones(repeated.size, dtype=bool)
        for values in recording.signals.values():
            a, b = values[repeated], values[repeated - 1]
            same &= (a == b) | (np.isnan(a) & np.isnan(b))
        if not same.all():
            k = int(repeated[~same][0])
            raise AeropendError(f'{where}: samples {k - 1} and {k} have the same time stamp t = {time[k]:.6f} s but '
                                'different values; which one is right cannot be told: fix the time stamps')
    backwards = np.flatnonzero(step < 0) + 1
    if backwards.size:
        k = int(backwards[0])
        raise AeropendError(f'{where}: time stamps go backwards at sample {k} (t = {time[k - 1]:.6f} s then '
                            f'{time[k]:.6f} s; {backwards.size} place(s) in all); the samples are out of order: '
                            'sort them by time or split the record there')
    if repeated.size:
        keep = np.ones(len(time), dtype=bool)
        keep[repeated] = False
        warnings.warn(f'{where}: dropped {repeated.size} duplicated sample(s) (same time stamp and values as the '
                      f'one before; first at sample {repeated[0]})', stacklevel=2)
        return Recording(time[keep], {k: v[keep] for k, v in recording.signals.items()}, recording.source)
    return recording


def _load_bag(path: Path) -> Recording:
    """The ``/aeropend/samples`` of an MCAP bag (folder or ``.mcap``), see :func:`aeropend_core.io.bag.read_samples`."""
    from aeropend_core.io.bag import read_samples
    samples = read_samples(path)
    columns = {'t': samples['time']}
    # integer-nanosecond clocks (stamp_ns, receive_time_ns) do not survive float64; t already holds the stamps
    columns.update({k: v for k, v in samples.items() if k != 'time' and not k.endswith('_ns')})
    return from_columns(columns, source=str(path))

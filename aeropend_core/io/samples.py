"""The samples of one record: :class:`Recording` (a time vector and named signals, SI units) and the columns a
recording must or may have.

A leaf of io/: the data-quality gate (signals/) annotates with :class:`Recording` and io/recording.py calls the gate
when it loads a file, so the class lives here, below both, and the imports point one way.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from aeropend_core.errors import AeropendError

#: Columns every recording must have, with units; and the input, given as either column (the duty is turned into
#: Va by eq (8) by the data-quality gate). ``armature_current`` [A] is optional: without it (or when the gate finds
#: it is not the period-average current) identify and diagnose use the reduced model (``docs/reduced-model.md``).
REQUIRED_COLUMNS = {'t': 's', 'angle': 'rad'}
INPUT_COLUMNS = {'armature_voltage': 'V', 'duty': '1 (fraction)'}
#: Columns the full model uses when present.
OPTIONAL_COLUMNS = {'armature_current': 'A'}


@dataclass(frozen=True, eq=False)
class Recording:
    """Samples of one record.

    Parameters
    ----------
    time : ndarray, shape (n,) [s]
        Sample times.
    signals : dict of str -> ndarray, shape (n,) [SI unit of each column]
        Every other column: ``armature_voltage`` [V], ``armature_current`` [A], ``angle`` [rad], ``duty``
        (dimensionless fraction), ``true_*`` truth columns of a simulation.
    source : str [-]
        Where it came from (file path), for messages.
    findings : tuple of aeropend_core.signals.quality.Finding [-]
        What the reader and the data-quality gate found and repaired (empty: clean, or not checked yet).

    Examples
    --------
    >>> import numpy as np
    >>> from aeropend_core import Recording, from_columns
    >>> time = np.arange(0.0, 1.0, 0.002)                                                        # s
    >>> recording = from_columns({'t': time, 'duty': np.full(time.size, 0.5), 'angle': 0.1 * time}, source='made up')
    >>> isinstance(recording, Recording), len(recording), sorted(recording.signals)
    (True, 500, ['angle', 'duty'])
    """

    time: np.ndarray
    signals: dict[str, np.ndarray] = field(default_factory=dict)
    source: str = ''
    findings: tuple = ()

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
        findings = tuple(f for f in self.findings if f.where is None or (f.where[1] >= start and f.where[0] < stop))
        return Recording(self.time[keep], {k: v[keep] for k, v in self.signals.items()}, self.source, findings)

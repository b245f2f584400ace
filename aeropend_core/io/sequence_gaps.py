"""Loss accounting by sequence number: every gap in a counter that should advance by one is counted as lost.

Used by the recorder for ``/aeropend/samples`` (the acquisition counter inside each JointState, ``position[4]``:
a gap is a sample that never reached the bag, whether the link, the transport or a stalled recorder lost it)
and for topics with a single publisher (the DDS publication sequence number of each message).
"""
from __future__ import annotations

import struct
from dataclasses import dataclass

__all__ = ['SequenceGaps', 'joint_state_position']


@dataclass
class SequenceGaps:
    """Counts the messages missing between consecutive sequence numbers of one stream.

    Attributes
    ----------
    lost : int
        Messages missing in all (sum of the gaps).
    gaps : int
        Number of gaps.
    largest_gap : int
        Messages missing in the largest gap.
    largest_gap_after : int
        The sequence number just before the largest gap.
    restarts : int
        Times the counter went back or repeated (the source restarted; nothing is counted as lost across it).
    last : int or None
        The last sequence number seen.
    """

    lost: int = 0
    gaps: int = 0
    largest_gap: int = 0
    largest_gap_after: int = 0
    restarts: int = 0
    last: int | None = None

    def observe(self, sequence: int) -> int:
        """Take the next sequence number; returns how many messages are missing before it (0 if none)."""
        previous, self.last = self.last, sequence
        if previous is None:
            return 0
        step = sequence - previous
        if step == 1:
            return 0
        if step <= 0:
            self.restarts += 1
            return 0
        missing = step - 1
        self.lost += missing
        self.gaps += 1
        if missing > self.largest_gap:
            self.largest_gap, self.largest_gap_after = missing, previous
        return missing

    def reset(self) -> None:
        """Forget the last number (e.g. the publisher changed): the next one starts a new run."""
        self.last = None

    def describe(self) -> str:
        """'12305 lost in 1 gap(s), largest 12305 after sequence 1200' (or 'none lost')."""
        if not self.lost:
            text = 'none lost'
        else:
            text = (f'{self.lost} lost in {self.gaps} gap(s), largest {self.largest_gap} after sequence '
                    f'{self.largest_gap_after}')
        return text + (f'; counter restarted {self.restarts} time(s)' if self.restarts else '')


def joint_state_position(data: bytes, index: int) -> float | None:
    """``position[index]`` of a little-endian CDR ``sensor_msgs/msg/JointState``, or None if it has none.

    Only the header and the names are walked to find the position array; nothing is deserialised.
    """
    from aeropend_core.io.bag import _joint_state_layout
    layout = _joint_state_layout(data)
    if layout is None or index >= layout[1]:
        return None
    return struct.unpack_from('<d', data, layout[0] + 8 * index)[0]

"""The closed loop's ROS parameters, shared by the nodes that run the law (the sim node and the serial bridge).

The gains carry ros2_control ``pid_controller``'s names (``p``, ``i``, ``d``, ``i_clamp_*``, ``u_clamp_*``,
``antiwindup``, ``tracking_time_constant``, ``feedforward_gain``) plus the derivative filter, the setpoint weight
and the safety limits (:class:`aeropend_core.control.law.PidGains`). The nodes declare them themselves (so that
``--help``, which reads each node's own source, lists them); their names, help texts and the check live here once.
"""
from __future__ import annotations

import math
from collections.abc import Callable, Sequence

from aeropend_core.control.law import PidGains
from aeropend_core.errors import AeropendError

#: Control modes: the duty command (open loop, the default), or the controller law on the measured angle.
CONTROL_MODES = ('open_loop', 'closed_loop')
#: The gain parameters, in PidGains' order; all numbers but antiwindup.
GAIN_NAMES = tuple(PidGains.__dataclass_fields__)
NUMERIC_GAIN_NAMES = tuple(name for name in GAIN_NAMES if name != 'antiwindup')
#: Their defaults without a controller file.
DEFAULT_GAINS = PidGains().as_dict()
GAIN_HELP = {
    'p': 'proportional gain [duty/rad]', 'i': 'integral gain [duty/(rad s)]', 'd': 'derivative gain on the '
    'measured angle [duty s/rad]', 'derivative_filter_time': 'Tf of the derivative filter [s] (0: plain difference)',
    'i_clamp_min': 'lower limit of the integral term [duty]', 'i_clamp_max': 'upper limit of the integral term '
    '[duty]', 'u_clamp_min': 'lowest duty the law outputs [fraction]', 'u_clamp_max': 'highest duty the law '
    'outputs [fraction]', 'antiwindup': 'back_calculation, conditional_integration or none',
    'tracking_time_constant': 'Tt of back-calculation [s] (0: sqrt(Ti Td))', 'feedforward_gain': 'weight of the '
    "model's static feedforward duty [-]", 'angle_min': 'safety trip below this measured angle [rad]',
    'angle_max': 'safety trip above this measured angle [rad]', 'setpoint_weight': 'b, the weight of the reference '
    'in the proportional term p (b r - y) [-] (1: plain PID; below 1: a smaller kick at a reference step)'}

#: The range of each numeric gain parameter (what rclpy enforces; PidGains checks their relations).
GAIN_RANGES = {'p': (0.0, 100.0), 'i': (0.0, 1000.0), 'd': (0.0, 100.0), 'derivative_filter_time': (0.0, 10.0),
               'i_clamp_min': (-1.0, 1.0), 'i_clamp_max': (-1.0, 1.0), 'u_clamp_min': (0.0, 1.0),
               'u_clamp_max': (0.0, 1.0), 'tracking_time_constant': (0.0, 100.0), 'feedforward_gain': (0.0, 2.0),
               'angle_min': (-math.pi, math.pi), 'angle_max': (-math.pi, math.pi), 'setpoint_weight': (0.0, 1.0)}


def gain_refusal(node_name: str, gains: PidGains, changed: dict) -> str | None:
    """Why a parameter change is refused (the gains it leaves, checked together), or None when it is accepted;
    `changed` may hold other parameters too (only the gains are judged)."""
    gains_changed = {name: value for name, value in changed.items() if name in GAIN_NAMES}
    if not gains_changed:
        return None
    problems = gain_problems({**gains.as_dict(), **gains_changed})
    if not problems:
        return None
    return f'{node_name}: controller gains refused: {"; ".join(problems)}; the gains are unchanged'


def gains_of(node) -> PidGains:
    """The node's gain parameters as they are now (after an accepted change)."""
    return PidGains(**{name: node.get_parameter(name).value for name in GAIN_NAMES})


def gain_problems(values: dict) -> list[str]:
    """What is wrong with a set of gain values (:meth:`PidGains.problems`), one sentence each."""
    gains = object.__new__(PidGains)            # unchecked: problems() says what the constructor would refuse
    for name, value in values.items():
        object.__setattr__(gains, name, value)
    return gains.problems()


def checked_reference(data: Sequence[float], gains: PidGains,
                      feedforward_of: Callable[[float], float]) -> tuple[float, float] | str:
    """``(reference [rad], feedforward [duty])`` of an ``aeropend/reference`` message's data ([reference_rad] or
    [reference_rad, feedforward_duty]; the feedforward of `feedforward_of` when not given), or why it is refused."""
    data = list(data)
    if not 1 <= len(data) <= 2 or not all(math.isfinite(value) for value in data):
        return (f'reference {data!r} refused: data must be [reference_rad] or [reference_rad, feedforward_duty], '
                'finite')
    reference = float(data[0])
    if not gains.angle_min <= reference <= gains.angle_max:
        return (f'reference {reference:.3f} rad refused: outside the safety limits [{gains.angle_min:g}, '
                f'{gains.angle_max:g}] rad')
    if len(data) > 1:
        feedforward = float(data[1])
    else:
        try:
            feedforward = float(feedforward_of(reference))
        except AeropendError as error:
            return f'reference {reference:.3f} rad refused: {error}'
    if not 0.0 <= feedforward <= 1.0:
        return f'feedforward {feedforward!r} refused: a duty fraction in [0, 1]'
    return reference, feedforward

"""Effects confined to part of the state space, for bench/state_map.py: the simulator runs them, the catalog lacks them.

Loaded with :func:`aeropend_core.model.effects.load_effects_module`; pendulum-kind effects in SI units per unit inertia.
Each is zero outside its region (an angle band, one direction of motion, a thrust range), with smooth edges.
"""
import numpy as np

from aeropend_core.model.effects import EffectParameter, register_effect


def _band(angle, centre, width):
    """1 inside [centre - width/2, centre + width/2] [rad], raised-cosine edges 1 deg wide, 0 outside."""
    edge = np.radians(1.0)
    distance = np.abs(angle - centre) - 0.5 * width
    ramp = 0.5 * (1.0 - np.cos(np.pi * distance / edge))
    return np.where(distance <= -edge, 1.0, np.where(distance >= 0.0, 0.0, ramp))


@register_effect('local_band_torque', 'a torque only inside one band of angles (a cable touching a stop, a rub)',
                 parameters=[EffectParameter('local_band_level', 'rad/s^2', 'level', 2.0, -100.0, 100.0),
                             EffectParameter('local_band_centre', 'rad', 'centre', 0.6, -3.2, 3.2),
                             EffectParameter('local_band_width', 'rad', 'width', 0.17, 0.02, 3.0)], replace=True)
def band_torque(angle, angular_rate, local_band_level, local_band_centre, local_band_width):
    return -local_band_level * _band(angle, local_band_centre, local_band_width)


@register_effect('local_band_friction', 'dry friction only inside one band of angles (a damaged bearing race)',
                 parameters=[EffectParameter('local_friction_level', 'rad/s^2', 'level', 3.0, 0.0, 100.0),
                             EffectParameter('local_friction_centre', 'rad', 'centre', 0.6, -3.2, 3.2),
                             EffectParameter('local_friction_width', 'rad', 'width', 0.17, 0.02, 3.0)], replace=True)
def band_friction(angle, angular_rate, local_friction_level, local_friction_centre, local_friction_width):
    return (-local_friction_level * np.tanh(angular_rate / 0.02)
            * _band(angle, local_friction_centre, local_friction_width))


@register_effect('local_rising_drag', 'a drag only while the rod rises (a flap, an asymmetric wake)',
                 parameters=[EffectParameter('local_rising_level', '1/s', 'level', 1.5, 0.0, 100.0)], replace=True)
def rising_drag(angle, angular_rate, local_rising_level):
    return -local_rising_level * np.maximum(angular_rate, 0.0)


@register_effect('local_high_thrust_loss', 'thrust lost above a level (propeller stall, supply sag)',
                 parameters=[EffectParameter('local_loss_share', '1', 'share lost above the knee', 0.3, 0.0, 1.0),
                             EffectParameter('local_loss_knee', 'rad/s^2', 'knee', 25.0, 0.0, 1000.0)], replace=True)
def high_thrust_loss(angle, angular_rate, thrust, local_loss_share, local_loss_knee):
    return -local_loss_share * np.maximum(thrust - local_loss_knee, 0.0)


@register_effect('local_falling_friction', 'dry friction only while the rod falls (a ratchet, a one-way clutch)',
                 parameters=[EffectParameter('local_falling_level', 'rad/s^2', 'level', 3.0, 0.0, 100.0)],
                 replace=True)
def falling_friction(angle, angular_rate, local_falling_level):
    return local_falling_level * np.clip(-angular_rate / 0.02, 0.0, 1.0)


@register_effect('local_wavy_torque', 'a torque rippling with the angle (a bent shaft, a cable that winds on)',
                 parameters=[EffectParameter('local_wavy_level', 'rad/s^2', 'level', 1.5, 0.0, 100.0),
                             EffectParameter('local_wavy_phase', 'rad', 'phase', 0.0, -10.0, 10.0)], replace=True)
def wavy_torque(angle, angular_rate, local_wavy_level, local_wavy_phase):
    return -local_wavy_level * (np.sin(9.0 * angle + local_wavy_phase) + 0.6 * np.sin(17.0 * angle
                                                                                   + 2.0 * local_wavy_phase))

"""Effects outside the catalog for bench/discovery.py and tests/test_discovery.py: the simulator runs them, the catalog
lacks them.

Loaded with :func:`aeropend_core.model.effects.load_effects_module` (as ``--effects-module`` does); each is a
pendulum-kind effect in SI units per unit inertia.
"""
import numpy as np

from aeropend_core.model.effects import EffectParameter, register_effect


@register_effect('test_stribeck', 'breakaway friction above the Coulomb level, fading with speed (Stribeck)',
                 parameters=[EffectParameter('test_stribeck_level', 'rad/s^2', 'breakaway excess', 5.0, 0.0, 100.0),
                             EffectParameter('test_stribeck_speed', 'rad/s', 'Stribeck speed', 0.15, 0.01, 5.0)],
                 replace=True)
def stribeck(angle, angular_rate, test_stribeck_level, test_stribeck_speed):
    return -test_stribeck_level * np.exp(-(angular_rate / test_stribeck_speed) ** 2) * np.tanh(angular_rate / 0.01)


@register_effect('test_power_damping', 'damping growing with |rate|^1.5 (neither linear nor quadratic)',
                 parameters=[EffectParameter('test_power_coefficient', '1/(rad^0.5 s^0.5)', 'coefficient', 1.5, 0.0,
                                             100.0)], replace=True)
def power_damping(angle, angular_rate, test_power_coefficient):
    return -test_power_coefficient * np.abs(angular_rate) ** 1.5 * np.sign(angular_rate)


@register_effect('test_inflow', 'thrust falls with the rod speed through the propeller inflow',
                 parameters=[EffectParameter('test_inflow_loss', 's/rad', 'relative thrust loss per rod rate', 0.05,
                                             0.0, 1.0)], replace=True)
def inflow(angle, angular_rate, test_inflow_loss, thrust):
    return -test_inflow_loss * thrust * angular_rate


@register_effect('test_second_harmonic', 'a torque periodic twice per turn (magnet / encoder eccentricity)',
                 parameters=[EffectParameter('test_harmonic_amplitude', 'rad/s^2', 'amplitude', 6.0, -100.0, 100.0)],
                 replace=True)
def second_harmonic(angle, angular_rate, test_harmonic_amplitude):
    return -test_harmonic_amplitude * np.sin(2.0 * angle)


@register_effect('test_cubic_spring', 'a hardening spring at the pivot (a cable stiffening with twist)',
                 parameters=[EffectParameter('test_cubic_stiffness', '1/(s^2 rad^2)', 'cubic spring', 30.0, 0.0,
                                             1000.0)], replace=True)
def cubic_spring(angle, angular_rate, test_cubic_stiffness):
    return -test_cubic_stiffness * angle ** 3


@register_effect('test_saturating_friction', 'friction that saturates smoothly above 0.5 rad/s (not in the '
                 'discovery vocabulary: the nearest terms must do)',
                 parameters=[EffectParameter('test_saturating_level', 'rad/s^2', 'saturated level', 4.0, 0.0, 100.0)],
                 replace=True)
def saturating_friction(angle, angular_rate, test_saturating_level):
    return -test_saturating_level * np.tanh(angular_rate / 0.5)

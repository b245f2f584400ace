"""aeropend_core: the aeropendulum's physics, simulation, identification and file I/O, with no ROS import.

SI units everywhere (rad, rad/s, V, A, s). Arrays are time-first, shape ``(n_samples,)`` or
``(n_samples, n_signals)``.
"""

__version__ = '0.1.0'

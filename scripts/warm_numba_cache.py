"""Compile aeropend's numba kernels into their on-disk cache (run by scripts/setup.sh after installing).

Without this the first identification window after a fresh set-up spends 10-20 s compiling, and the online node
skips the windows that come due meanwhile. The kernels are compiled by running the real entry points once on a
short simulated record (every catalog effect is tried by the diagnosis, so every kernel variant is built);
numba keeps the machine code in ``__pycache__`` next to each module and reloads it in ~1 s.
Re-running is cheap (everything loads from the cache); a kernel is rebuilt when its module's source changes, or
(aeropend_core.kernel_cache) a module it is compiled from.
"""
from __future__ import annotations

import sys
import time
import warnings


def main() -> int:
    started = time.perf_counter()
    from aeropend_core.diagnosis.diagnose import diagnose
    from aeropend_core.diagnosis.online import analyze_window
    from aeropend_core.identify.pendulum import identify_full_state, identify_pendulum
    from aeropend_core.io.recording import from_columns
    from aeropend_core.sim.excitation import lhc_schedule
    from aeropend_core.sim.noise import MeasurementNoise
    from aeropend_core.sim.simulate import simulate

    duration = 30.0
    run = simulate(lhc_schedule(duration, seed=1).duty(duration=duration),
                   noise=MeasurementNoise(psnr_db=40, quantise=True), seed=1)
    identify_pendulum(run.time, run.armature_voltage, run.armature_current, run.angle, duty=run.duty)
    identify_full_state({'t': run.time, **run.truth})
    analyze_window(run.time, run.armature_voltage, run.armature_current, run.angle)
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        diagnose(from_columns(run.columns(with_truth=False), source='warm-up'))
        # the closed loop's kernels (the compiled loop, the law, the linear search's loop)
        import math

        from aeropend_core.control.design import design
        from aeropend_core.control.metrics import Template
        design(Template(), math.radians(40))
    print(f'warm_numba_cache: kernels compiled and cached in {time.perf_counter() - started:.1f} s')
    return 0


if __name__ == '__main__':
    sys.exit(main())

"""The text report of a diagnosis, printed by ``aeropend diagnose`` (units stated on every number)."""
from __future__ import annotations


from aeropend_core.diagnosis.compare import excess_error
from aeropend_core.present.verdict_text import size_text, verdict_of
from aeropend_core.model.effects import find_parameter
from aeropend_core.model.names import NOMINAL_PARAMETERS
from aeropend_core.signals.reduced import MAP_PARAMETERS
from aeropend_core.present.result_types import DiagnosisLike



def format_summary(diagnosis: DiagnosisLike, source: str | None = None) -> str:
    """The text report printed by ``aeropend diagnose``: the verdict in two layers, one plain sentence
    (:func:`~aeropend_core.present.plain_verdict.plain_verdict`; `source`, the record's name, goes into its next
    command) and the evidence (:func:`~aeropend_core.present.verdict_text.verdict_of`)."""
    current = diagnosis.current
    noise = current.noise_rms
    from aeropend_core.signals.quality import quality_lines
    lines = [quality_lines(diagnosis.findings)]      # the data's doubts first, before any number
    model = 'nominal' + ''.join(f' + {e}' for e in diagnosis.effects)
    lines.append(f'Model: {model}')
    lines.append(f'Held-out free-run simulation of the angle: fit {current.fit_percent:.2f} % (NRMSE, MATLAB '
                 f'compare), RMS error {current.rms_error * 1e3:.2f} mrad, measurement noise {noise * 1e3:.2f} mrad, '
                 f'error beyond noise {excess_error(current.rms_error, noise) * 1e3:.2f} mrad')
    lines.append(f'{current.evaluation.prediction_horizon:g} s-ahead prediction RMS error '
                 f'{current.evaluation.prediction_rms * 1e3:.2f} mrad')
    if diagnosis.prepared is not None and diagnosis.prepared.motor is not None:
        motor = diagnosis.prepared.motor
        lines.append(f'Armature current by the motor observer: RMS error {motor.current_rms_error * 1e3:.2f} mA, '
                     f'current noise {motor.current_noise_rms * 1e3:.2f} mA'
                     + (f' (beyond 1.5x the noise, kept: its thrust voltage is off by at most '
                        f'{motor.voltage_error_bound * 1e3:.2f} mV, Va - R Ia by '
                        f'{motor.fallback_voltage_error * 1e3:.2f} mV)' if motor.kept_against_fallback else ''))
    prep = diagnosis.prepared
    if prep is not None and prep.reduced and prep.motor_map:
        lines.append('Reduced model (no period-average armature current): thrust k e|e| with T de/dt = Va - e - q e|e| '
                     f'(T, q profiled; residual {prep.motor_map["residual_rms"] * 1e3:.2f} mrad on the training part)')
    from aeropend_core.diagnosis.checks import misfit_doubt
    lines.append('Parameters (SI, +- 1 sigma' + ('; the model misses the data: biased by what it misses, see the first '
                                               'note' if misfit_doubt(diagnosis) else '') + '):')
    observer = prep is not None and prep.motor is not None
    errors = diagnosis.reported_errors(current)
    warnings = diagnosis.parameter_warnings
    from aeropend_core.diagnosis.doubts import rate_doubts
    doubts = rate_doubts(getattr(prep, 'sample_time', None), getattr(prep, 'reduced', False))
    doubts.update(getattr(diagnosis, 'parameter_doubts', {}))         # e.g. Ra against a current's scale
    for name, value in diagnosis.reported_parameters(current).items():
        error = errors.get(name, float('nan'))
        found = find_parameter(name)
        unit = NOMINAL_PARAMETERS[name][0] if name in NOMINAL_PARAMETERS else (found[1].unit if found else '')
        unit = MAP_PARAMETERS.get(name, unit)
        flag = f'   !! {warnings[name]}' if name in warnings else ''
        flag += f'   ~ {doubts[name]}' if name in doubts else ''
        if name == 'armature_resistance' and observer:
            lines.append(f'  {name:24s} {value:12.5g} +- {error:9.2g} {unit} (from the motor observer fitted to Ia)'
                         f'{flag}')
            continue
        if name in diagnosis.fixed:
            where = diagnosis.fixed_from.get(name, '--fix')
            lines.append(f'  {name:24s} {diagnosis.fixed[name]:12.5g} {unit} (fixed from {where}, not fitted)')
            continue
        lines.append(f'  {name:24s} {value:12.5g} +- {error:9.2g} {unit}{flag}')
    if diagnosis.before is not None:
        before = diagnosis.before
        lines.append('Before -> after adding ' + ', '.join(diagnosis.effects) + ':')
        lines.append(f'  fit {before.fit_percent:.2f} % -> {current.fit_percent:.2f} %; error beyond noise '
                     f'{excess_error(before.rms_error, noise) * 1e3:.2f} -> '
                     f'{excess_error(current.rms_error, noise) * 1e3:.2f} mrad')
        for name in NOMINAL_PARAMETERS:
            if name in before.parameters and name in current.parameters and name != 'armature_resistance':
                old, new = before.parameters[name], current.parameters[name]
                lines.append(f'  {name:24s} {old:10.4g} -> {new:10.4g} ({(new - old) / old * 100:+.1f} %)')
        for name, stats in current.evaluation.regimes.items():
            if name in before.evaluation.regimes:
                lines.append(f'  {name}: {before.evaluation.regimes[name]["rms_error"] * 1e3:.1f} -> '
                             f'{stats["rms_error"] * 1e3:.1f} mrad')
    lines.append('Where the model fails (RMS error by regime, mrad; ratio to overall):')
    for name, stats in sorted(current.evaluation.regimes.items(), key=lambda kv: -kv[1]['ratio_to_overall']):
        lines.append(f'  {stats["rms_error"] * 1e3:7.2f}  x{stats["ratio_to_overall"]:.2f}  {name} '
                     f'({stats["fraction_of_samples"] * 100:.0f} % of samples)')
    lines.append('Worst 1-s windows:')
    for window in current.evaluation.worst_windows[:3]:
        lines.append(f'  t = {window["start"]:.1f}-{window["stop"]:.1f} s ({window["part"]}): '
                     f'{window["rms_error"] * 1e3:.2f} mrad, input {window["input"]}')
    from aeropend_core.diagnosis.doubts import unresolvable
    prepared = getattr(diagnosis, 'prepared', None)
    sample_time = getattr(prepared, 'sample_time', None) if prepared is not None else None
    lines.append('Candidates (best first):')
    for candidate in diagnosis.candidates:
        if candidate.comparison is None:
            lines.append(f'  {candidate.effect:18s} not testable: {candidate.error}')
            continue
        flag = 'SIGNIFICANT' if candidate.significant else ('held-out' if candidate.heldout_only else 'no')
        params = ', '.join(f'{k} = {v:.4g}' for k, v in candidate.parameters.items())
        if sample_time and unresolvable(candidate.effect, candidate.parameters, sample_time):
            params += ' (below one sample: not resolvable at this rate)'
        lines.append(f'  {candidate.effect:18s} fit {candidate.fit_percent:6.2f} %  beyond noise '
                     f'{candidate.excess_after * 1e3:6.2f} mrad  dBIC {candidate.delta_bic:9.1f}  {flag:11s} '
                     f'{params}')
    if diagnosis.found:
        lines.append('Selected set (forward selection with backward elimination; error beyond noise when added):')
        for f in diagnosis.found:
            conf = f'  confounded with {", ".join(f.confounded_with)}' if f.confounded_with else ''
            lines.append(f'  {size_text(f)}: {f.excess_before * 1e3:.2f} -> {f.excess_after * 1e3:.2f} mrad, '
                         f't = {f.t_statistic:.1f}, DM = {f.dm_statistic:+.1f}{conf}')
        final = diagnosis.final
        lines.append(f'  with the set: fit {final.fit_percent:.2f} %, error beyond noise '
                     f'{excess_error(final.rms_error, noise) * 1e3:.2f} mrad')
    if diagnosis.drift:
        lines.append('Drift test (nominal parameters fitted per stretch, trend against time):')
        for row in diagnosis.drift:
            lines.append(f'  {row["parameter"]:18s} change {row["change"] * 100:+6.1f} % over {row["span"]:.0f} s, '
                         f't = {row["t_statistic"]:+.1f}, p = {row["p_value"]:.2g} '
                         f'({row["stretches"]} stretches){"  DRIFT" if row["drifting"] else ""}')
    from aeropend_core.present.discovery_text import discovery_lines, motor_lines
    lines += discovery_lines(getattr(diagnosis, 'discovery', None))
    lines += motor_lines(getattr(diagnosis, 'motor_discovery', None))
    from aeropend_core.present.plain_verdict import plain_verdict
    lines.append('Verdict: ' + plain_verdict(diagnosis, source))
    lines.append('Evidence: ' + verdict_of(diagnosis))
    for note in diagnosis.notes:
        lines.append('Note: ' + note)
    for row in diagnosis.residual_structure:
        lines.append(f'  residual vs {row["signature"]}: r = {row["correlation"]:+.2f}')
    from aeropend_core.present.state_map_text import state_map_lines
    lines += state_map_lines(diagnosis)
    remainder = getattr(diagnosis, 'remainder', None)
    if remainder is not None and remainder.material:
        lines.append(remainder.sentence())
    if diagnosis.missing_effect:
        best = next(c for c in diagnosis.candidates if c.effect == diagnosis.missing_effect)
        lines.append('Why: ' + best.explanation)
    lines.append(f'({diagnosis.seconds:.1f} s)')
    return '\n'.join(lines)


__all__ = ['format_summary']

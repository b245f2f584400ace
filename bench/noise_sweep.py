"""Noise sweep: aeropend's WSINDy vs pysindy's weak form vs strong-form SINDy, time per window and coefficient error
at PSNR 60/50/40/30/20 dB on exactly the same data.

Problem (the full-state case of the paper "Data-Driven System Identification of an Aeropendulum", as in
bench_wsindy.py): one 10 s window (4,900 samples at 490 Hz) of the
simulated rig under an LHC duty schedule, X = [Ia, ω1, y, Ω] with input Va, white noise at the given PSNR on all
five signals; the same 18 candidate terms for every method (constant, linear, products and squares of the states,
sin y, cos y, Va linear only, in all four equations dIa/dt, dω1/dt, dy/dt, dΩ/dt). Seeds 0..N-1 give N windows
(schedule, simulation and noise) per PSNR; every method sees the same N windows.

Methods:

* **WSINDy**: ``aeropend_core.identify.pendulum.identify_full_state`` (full method, automatic threshold), Va
  offered to every equation (exactly the 18 terms above); kernel caches cleared before every timed call.
* **WSINDy, own library** (extra row, not the same library): aeropend's default, Va offered to dIa/dt only, as the
  tool runs it (offering Va to dω1/dt makes {Ia, Va} and {Ia, ω1} near-equivalent at high noise).
* **pysindy weak**: ``WeakPDELibrary`` (K = 100, p = 4) over a ``CustomLibrary`` of the 18 terms, ``STLSQ``
  (normalised columns, alpha 1e-8), ``fit(x, t=..., u=...)``.
* **pysindy strong**: ``SINDy`` with the same ``CustomLibrary``, ``FiniteDifference`` (2nd order) derivatives of the
  noisy states, the same ``STLSQ``.

The baselines' STLSQ threshold is absolute, so for every window and every equation the best threshold of a grid
(half-decades 1e-2 .. 1e8; the top one empties an equation) is chosen **with the truth** (lowest coefficient error
of that equation, then fewest terms): this favours the baselines (a user has no truth; the best single threshold for
all four equations is worse, recorded as ``single_threshold`` in the JSON). A baseline is timed as one fit of all
four equations at the threshold chosen for dΩ/dt (the time hardly depends on the threshold; refitting per equation
would cost more and is not counted), median of R calls, with the default BLAS threads and with one BLAS thread, the
faster counts.

Figures per method and PSNR (median over the seeds; time: median over the seeds of the per-window median):

* **coefficient error**: the largest over the four equations of ‖ξ̂ₑ − ξₑ‖₂ / ‖ξₑ‖₂, the relative L2 error of the
  equation's coefficient vector over all 18 terms (spurious terms count, missing ones count as error 100 %);
  each equation on its own scale, since the whole-matrix norm would only see dω1/dt's 4404·Ia term (that one is
  in the JSON as ``matrix_error``). WSINDy's floor of ~7 % is dIa/dt's overall scale 1/La: with La/Ra ≈ one
  sample the current is slaved to Va − Kω·ω1 except for ~1-sample kicks at the duty steps, which alone fix 1/La; its
  three coefficients come out ~7 % low together even on noise-free data (their ratios, Ra and Kω, are exact);
* **dΩ/dt error**: the same for the pendulum equation alone (the paper's equation of interest);
* **wrong terms**: spurious + missing terms over the four equations (10 true terms of 72);
* **Kq error**: |relative error| of the thrust coefficient from the ω1² coefficient of dΩ/dt;
* **time per window** [ms].

Outputs: a markdown table on stdout and in ``noise_sweep.md``, a plot ``noise_sweep.png`` (coefficient error, Kq
error, wrong terms and time vs PSNR, log y, the paper's 50 dB point marked) and ``noise_sweep.json`` (every window's
figures plus the key figures for bench/run_all.py), in the folder of ``--json`` (default bench/results/latest/).

Run:  .venv/bin/python bench/noise_sweep.py [--quick] [--seeds 3] [--json PATH]
Run time on the 2-core project machine (load average ~3): ~34 s per seed (5 windows of ~5 s plus start-up), so the
default 3 seeds ~1.7 min, --seeds 5 (what bench/run_all.py runs) ~2.8 min, --quick (1 seed, decade grid) ~50 s.
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

from _common import (SAME_LIBRARY, STATES, THRESHOLD_GRID, add_json_argument, coefficient_error, equation_error,
                     figure, fit_pysindy, make_window, matrix_error, pysindy_with_truth, run_ours, score,
                     time_both_blas, write_json)

ROOT = Path(__file__).resolve().parents[1]
PSNRS = (60.0, 50.0, 40.0, 30.0, 20.0)
PAPER_PSNR = 50.0
METHODS = {'wsindy': 'aeropend WSINDy', 'wsindy_default': 'aeropend WSINDy, own library*',
           'pysindy_weak': 'pysindy weak (WeakPDELibrary+STLSQ)',
           'pysindy_strong': 'pysindy strong (FiniteDifference+STLSQ)'}
FULL_GRID = THRESHOLD_GRID                      # 1e-2 ... 1e8, half-decades (1e8 empties every equation)
QUICK_GRID = THRESHOLD_GRID[::2]                # decades


def window_figures(coefficients: dict[str, dict[str, float]]) -> dict:
    wrong, kq, worst = score(coefficients)
    return {'coefficient_error': coefficient_error(coefficients), 'matrix_error': matrix_error(coefficients),
            'equation_errors': {eq: equation_error(coefficients[eq], eq) for eq in STATES},
            'wrong_terms': wrong, 'kq_error': kq, 'worst_true_coefficient_error': worst}


def run_baseline(data, form: str, grid: list[float], repeats: int) -> dict:
    """Per-equation best threshold of `grid` (chosen with the truth), its coefficients and the fit time."""
    best = pysindy_with_truth(data, form, grid)
    timings = time_both_blas(lambda: fit_pysindy(data, best['threshold'], form), repeats)
    single = best['single']
    return {'time': min(timings.values()), 'timings': timings, 'coefficients': best['coefficients'],
            'thresholds': best['thresholds'],
            'single_threshold': {'threshold': single['threshold'], **window_figures(single['coefficients'])}}


def sweep(psnrs, seeds: int, grid: list[float], repeats: int, base_repeats: int, log=print) -> list[dict]:
    rows = []
    for psnr in psnrs:
        for seed in range(seeds):
            data = make_window(seed, psnr)
            t0 = time.perf_counter()
            ours_time, ours_coef = run_ours(data, repeats, **SAME_LIBRARY)
            default_time, default_coef = run_ours(data, repeats)
            runs = {'wsindy': {'time': ours_time, 'coefficients': ours_coef},
                    'wsindy_default': {'time': default_time, 'coefficients': default_coef}}
            for form in ('weak', 'strong'):
                runs[f'pysindy_{form}'] = run_baseline(data, form, grid, base_repeats)
            for method, run in runs.items():
                rows.append({'method': method, 'psnr_db': psnr, 'seed': seed, 'time_s': run['time'],
                             **window_figures(run['coefficients']),
                             **{k: run[k] for k in ('timings', 'thresholds', 'single_threshold') if k in run},
                             'coefficients': run['coefficients']})
            last = rows[-len(runs):]
            log(f'  PSNR {psnr:g} dB seed {seed}: ' + ', '.join(
                f'{r["method"]} {r["time_s"] * 1e3:.1f} ms err {r["coefficient_error"]:.3g}' for r in last)
                + f'  ({time.perf_counter() - t0:.1f} s)', file=sys.stderr)
    return rows


def summarise(rows: list[dict]) -> dict:
    """{method: {psnr: medians over the seeds}}."""
    out = {}
    for method in METHODS:
        out[method] = {}
        for psnr in sorted({r['psnr_db'] for r in rows}, reverse=True):
            sel = [r for r in rows if r['method'] == method and r['psnr_db'] == psnr]
            out[method][psnr] = {
                'time_s': statistics.median(r['time_s'] for r in sel),
                'coefficient_error': statistics.median(r['coefficient_error'] for r in sel),
                'coefficient_error_range': [min(r['coefficient_error'] for r in sel),
                                            max(r['coefficient_error'] for r in sel)],
                'matrix_error': statistics.median(r['matrix_error'] for r in sel),
                'pendulum_error': statistics.median(r['equation_errors']['angular_rate'] for r in sel),
                'wrong_terms': statistics.median(r['wrong_terms'] for r in sel),
                'kq_error': statistics.median(r['kq_error'] for r in sel),
                'kq_error_range': [min(r['kq_error'] for r in sel), max(r['kq_error'] for r in sel)],
                'windows': len(sel),
            }
    return out


def markdown_table(summary: dict, seeds: int) -> str:
    lines = [f'Median over {seeds} window(s) per PSNR (10 s, 490 Hz, 18-term library, 4 equations). '
             'Coefficient error: worst equation\'s relative L2 error (dΩ/dt error: the pendulum equation\'s); '
             'baselines\' thresholds chosen with the truth '
             'per equation (favours them). ★ = the paper\'s 50 dB point. *own library: aeropend\'s default, Va '
             'offered to dIa/dt only (17 terms in the other three equations), not the same library as the rest.',
             '',
             '| PSNR [dB] | method | time/window [ms] | coefficient error | dΩ/dt error | wrong terms (of 72) '
             '| Kq error |',
             '| --- | --- | ---: | ---: | ---: | ---: | ---: |']
    for psnr in next(iter(summary.values())):
        for method, label in METHODS.items():
            s = summary[method][psnr]
            mark = ' ★' if psnr == PAPER_PSNR else ''
            lines.append(f'| {psnr:g}{mark} | {label} | {s["time_s"] * 1e3:.1f} | {s["coefficient_error"]:.3g} | '
                         f'{s["pendulum_error"]:.3g} | {s["wrong_terms"]:g} | {s["kq_error"] * 100:.2f} % |')
    return '\n'.join(lines) + '\n'


def plot(summary: dict, rows: list[dict], path: Path, title: str) -> None:
    """2 x 2 panels against PSNR: coefficient error, Kq error, wrong terms, time per window (medians as lines,
    each window as a faint dot; log y except wrong terms)."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    colours = {'wsindy': 'tab:blue', 'wsindy_default': 'tab:purple', 'pysindy_weak': 'tab:orange',
               'pysindy_strong': 'tab:green'}
    fig, axes = plt.subplots(2, 2, figsize=(12, 8.5))
    panels = (('coefficient_error', 'coefficient error (worst equation, relative L2)', True),
              ('kq_error', 'Kq relative error', True),
              ('wrong_terms', 'wrong terms (spurious + missing, of 72)', False),
              ('time_ms', 'time per window [ms]', True))
    from matplotlib.ticker import FormatStrFormatter
    rows = [{**r, 'time_ms': r['time_s'] * 1e3} for r in rows]
    summary = {m: {p: {**v, 'time_ms': v['time_s'] * 1e3} for p, v in by_psnr.items()}
               for m, by_psnr in summary.items()}
    for ax, (key, ylabel, log) in zip(axes.flat, panels):
        floor = 1e-6 if log else -1e9
        for method, label in METHODS.items():
            psnrs = list(summary[method])
            ax.plot(psnrs, [max(summary[method][p][key], floor) for p in psnrs], marker='o', color=colours[method],
                    label=label, ls=':' if method == 'wsindy_default' else '-')
            windows = [r for r in rows if r['method'] == method]
            ax.plot([r['psnr_db'] for r in windows], [max(r[key], floor) for r in windows], '.',
                    color=colours[method], alpha=0.35)
        ax.axvline(PAPER_PSNR, color='grey', ls='--', lw=1)
        ax.text(PAPER_PSNR, 0.98, " paper's 50 dB", transform=ax.get_xaxis_transform(), va='top', ha='left',
                fontsize=8, color='grey')
        if log:
            ax.set_yscale('log')
        if key == 'time_ms':
            ax.yaxis.set_major_formatter(FormatStrFormatter('%g'))
            ax.yaxis.set_minor_formatter(FormatStrFormatter('%g'))
        ax.set_xlabel('PSNR [dB] (noise grows to the right)')
        ax.set_ylabel(ylabel)
        ax.invert_xaxis()
        ax.grid(True, which='both', alpha=0.3)
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc='lower center', ncol=len(METHODS), fontsize=9)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout(rect=(0, 0.035, 1, 1))
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--quick', action='store_true',
                        help='1 seed, a decade threshold grid, fewer timing repeats (~50 s)')
    parser.add_argument('--seeds', type=int, default=None, help='windows per PSNR (default 3, --quick 1)')
    parser.add_argument('--psnr', type=float, nargs='+', default=list(PSNRS), help='PSNR levels [dB]')
    parser.add_argument('--repeats', type=int, default=None, help='timed WSINDy calls per window (default 5)')
    add_json_argument(parser)
    args = parser.parse_args()
    seeds = args.seeds if args.seeds is not None else (1 if args.quick else 3)
    repeats = args.repeats if args.repeats is not None else (3 if args.quick else 5)
    if seeds < 1 or repeats < 1:
        parser.error('--seeds and --repeats must be >= 1')
    base_repeats = 2 if args.quick else 3
    grid = QUICK_GRID if args.quick else FULL_GRID
    json_path = Path(args.json) if args.json else ROOT / 'bench' / 'results' / 'latest' / 'noise_sweep.json'
    json_path.parent.mkdir(parents=True, exist_ok=True)

    start = time.perf_counter()
    rows = sweep(args.psnr, seeds, grid, repeats, base_repeats)
    summary = summarise(rows)
    table = markdown_table(summary, seeds)
    print(table)
    title = (f'Full-state identification, 10 s window at 490 Hz, 18 terms; median of {seeds} seed(s); '
             'baselines\' thresholds chosen with the truth')
    png = json_path.with_suffix('.png')
    plot(summary, rows, png, title)
    json_path.with_suffix('.md').write_text(table, encoding='utf-8')

    figures = []
    paper = PAPER_PSNR if PAPER_PSNR in args.psnr else args.psnr[0]
    ours = summary['wsindy'][paper]
    short = {'pysindy_weak': 'pysindy weak', 'pysindy_strong': 'pysindy strong'}
    for method in short:
        base = summary[method][paper]
        ratio = base['time_s'] / ours['time_s']
        weak = method == 'pysindy_weak'
        figures.append(figure(f'time per window at {paper:g} dB, WSINDy vs {short[method]}', ours['time_s'] * 1e3,
                              'ms', baseline=base['time_s'] * 1e3, baseline_name=short[method], ratio=ratio,
                              ratio_meaning='speed-up (baseline time / ours)',
                              target='>= 10x, < 50 ms' if weak else '',
                              met=(ratio >= 10 and ours['time_s'] < 0.05) if weak else None))
    for method in short:
        base = summary[method][paper]
        figures.append(figure(f'coefficient error at {paper:g} dB, WSINDy vs {short[method]}',
                              ours['coefficient_error'], 'rel. L2', baseline=base['coefficient_error'],
                              baseline_name=short[method] + ' (thresholds chosen with the truth)',
                              ratio=base['coefficient_error'] / ours['coefficient_error']
                              if ours['coefficient_error'] else None,
                              ratio_meaning='baseline error / ours', target='below the baseline',
                              met=ours['coefficient_error'] < base['coefficient_error']))
    for key, label, units, scale in (('wrong_terms', 'wrong terms (of 72)', 'terms', 1),
                                     ('kq_error', 'Kq error', '%', 100)):
        for method in short:
            base = summary[method][paper]
            figures.append(figure(f'{label} at {paper:g} dB, WSINDy vs {short[method]}', ours[key] * scale, units,
                                  baseline=base[key] * scale, baseline_name=short[method],
                                  ratio_meaning='ours / baseline'))
    write_json(json_path, 'noise_sweep', figures, seeds=seeds, psnr_db=args.psnr, threshold_grid=grid,
               timing_repeats={'wsindy': repeats, 'baselines': base_repeats}, summary=summary, windows=rows,
               table_markdown=table, plot=png.name, run_time_s=time.perf_counter() - start)
    print(f'wrote {json_path}, {png.name}, {json_path.with_suffix(".md").name} '
          f'({time.perf_counter() - start:.0f} s)')
    return 0


if __name__ == '__main__':
    sys.exit(main())

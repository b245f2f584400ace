"""Per parameter: within 1 and 2 sigma and RMS z, before -> after, from two bench/second_rig.py --rows files (the same
seeds); and the records where any |z| > 2 on either side."""
import json
import math
import sys


def load(path):
    return {r['seed']: r for r in map(json.loads, open(path)) if not r.get('refused')}


before, after = load(sys.argv[1]), load(sys.argv[2])
seeds = sorted(set(before) & set(after))
names = sorted({n for s in seeds for n in before[s]['z']})
print(f'{len(seeds)} records on both sides\n')
print('| parameter | records | within 1σ before → after | within 2σ before → after | RMS z before → after |')
print('| --- | --- | --- | --- | --- |')
for name in names:
    pairs = [(before[s]['z'].get(name), after[s]['z'].get(name)) for s in seeds if name in before[s]['z']]

    def stats(zs):
        n = len(zs)
        finite = [abs(z) for z in zs if z is not None]
        return (sum(z <= 1 for z in finite) / n, sum(z <= 2 for z in finite) / n,
                math.sqrt(sum(z * z for z in finite) / max(len(finite), 1)))
    b, a = stats([p[0] for p in pairs]), stats([p[1] for p in pairs])
    print(f'| {name} | {len(pairs)} | {100 * b[0]:.0f} % → {100 * a[0]:.0f} % '
          f'| {100 * b[1]:.0f} % → {100 * a[1]:.0f} % | {b[2]:.2f} → {a[2]:.2f} |')
print()
for s in seeds:
    zb = {k: round(v, 1) for k, v in before[s]['z'].items() if v is not None and abs(v) > 2}
    za = {k: round(v, 1) for k, v in after[s]['z'].items() if v is not None and abs(v) > 2}
    if zb or za:
        print(f'- {s} ({", ".join(before[s]["true_effects"]) or "no effect"}, {before[s]["psnr_db"]} dB): before '
              f'{zb or "-"}; after {za or "-"}')

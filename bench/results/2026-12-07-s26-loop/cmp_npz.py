"""Compare two .npz files array by array: equal bit for bit (NaN equal to NaN) and the same sign bits.

    .venv/bin/python bench/results/2026-12-07-s26-loop/cmp_npz.py BASE.npz NEW.npz
"""
import sys

import numpy as np

a, b = np.load(sys.argv[1]), np.load(sys.argv[2])
same = 0
for key in a.files:
    x, y = a[key], b[key]
    if x.shape == y.shape and np.array_equal(x, y, equal_nan=True) and np.array_equal(np.signbit(x), np.signbit(y)):
        same += 1
    else:
        print('DIFFERENT', key)
print(f'{same} of {len(a.files)} arrays equal bit for bit (sign bits included); keys equal: {a.files == b.files}')

"""Run a node's ``main`` with tracemalloc on, and write what grew to a file every --every seconds.

Used by ``bench/load_test.py --trace-memory``: ``python bench/_traced_node.py OUT.txt EVERY MODULE --ros-args ...``.
Each report lists the 25 source lines whose live Python allocations grew most since the first snapshot taken
after the warm-up (``EVERY`` seconds after start), and the traced total; memory that Python does not allocate
(DDS, the allocator's own overhead) is not in it, which is what tells the two apart.
"""
from __future__ import annotations

import importlib
import sys
import threading
import time
import tracemalloc


def _reporter(path: str, every: float) -> None:
    baseline = None
    start = time.monotonic()
    while True:
        time.sleep(every)
        snapshot = tracemalloc.take_snapshot().filter_traces((tracemalloc.Filter(False, tracemalloc.__file__),
                                                              tracemalloc.Filter(False, '<frozen importlib*')))
        if baseline is None:
            baseline = snapshot
            continue
        current, peak = tracemalloc.get_traced_memory()
        lines = [f'--- t = {time.monotonic() - start:.0f} s: traced {current / 1e6:.3f} MB (peak {peak / 1e6:.3f})']
        for stat in snapshot.compare_to(baseline, 'lineno')[:25]:
            lines.append(f'  {stat.size_diff / 1024:+9.1f} KiB {stat.count_diff:+7d} blocks  {stat.traceback[0]}')
        with open(path, 'a', encoding='utf-8') as handle:
            handle.write('\n'.join(lines) + '\n')


def main() -> int:
    path, every, module = sys.argv[1], float(sys.argv[2]), sys.argv[3]
    sys.argv = [module, *sys.argv[4:]]
    tracemalloc.start(1)
    threading.Thread(target=_reporter, args=(path, every), daemon=True).start()
    return importlib.import_module(module).main()


if __name__ == '__main__':
    sys.exit(main())

"""Markdown table of the loop runs in this folder: python bench/results/2026-11-28-s13-loop6/table.py"""
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1]))        # bench/

from experiment_decide import table  # noqa: E402

print(table(HERE))

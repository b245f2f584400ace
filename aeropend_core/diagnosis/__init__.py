"""Compare model and data, find where it fails and which physical effect is missing."""

#: Shortest record the comparison accepts [s] (here, not in compare.py, so that a verb can refuse a too-short
#: duration without importing the diagnosis stack: scipy, numba).
MIN_DURATION = 20.0

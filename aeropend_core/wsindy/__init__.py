"""Weak SINDy: candidate-term libraries, test functions, weak-form regression and term selection."""

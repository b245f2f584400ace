"""Compare model and data, find where it fails and which physical effect is missing."""

"""Identification of the rig equations from recordings with weak SINDy."""

"""Test doubles for what cannot be on this machine: a pty-backed fake rig device."""

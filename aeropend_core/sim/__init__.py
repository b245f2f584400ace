"""The rig simulator, excitation schedules and measurement-noise injection."""

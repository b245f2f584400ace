"""The physical model: rig parameters (SI) and the catalog of physical effects."""

"""The ROS verbs of the `aeropend` command (registered through the `aeropend.verbs` entry-point group)."""

"""The rig hardware side without ROS: frame protocol, sample clock, calibration."""

"""Shared test set-up: tests never multicast off the machine (ROS 2 discovery stays on localhost)."""
import os

os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')

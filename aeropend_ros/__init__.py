"""aeropend_ros: thin ROS 2 nodes over aeropend_core. Importing this package does not import rclpy."""

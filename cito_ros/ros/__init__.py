"""The ROS 2 layer: the node, the conversions between ROS messages and the planner, the markers, the
declared parameters and the bags. The only layer that imports rclpy and the ROS interfaces."""

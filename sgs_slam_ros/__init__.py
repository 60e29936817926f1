"""ROS 2 nodes of SGS-SLAM: tracking_node, mapping_node, slam_node (both composed), bag_player.

The only package of the project that imports rclpy.
"""

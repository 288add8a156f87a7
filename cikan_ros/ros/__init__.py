"""The ROS 2 side of cikan_ros: message conversions, topics and QoS, nodes' shared plumbing,
the MCAP recorder, replay and the graph launcher.

Everything that imports rclpy lives here (and in the node packages ``sim_node``,
``governor_node``, ``controller_node``); the rest of the library runs without ROS.
"""

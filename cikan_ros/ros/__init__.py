"""The ROS 2 side of cikan_ros: message conversions (``convert``), the graph as data (topics,
nodes, arguments: ``graph_spec``, no rclpy), what the node processes share at run time (QoS,
readiness, executor: ``graph``), node parameters (``params``), bags (``bag_reader``, no rclpy;
``bag_writer``; the recorder node ``recorder_node``), replay, and the graph launcher (``launch``).

Everything that imports rclpy lives here (and in the node packages ``sim_node``,
``governor_node``, ``controller_node``); the rest of the library runs without ROS.

Use:

- ``cikan mission [--governor NAME] [--seed N] [--bag DIR] [--json]``: the four nodes as separate
  processes on an isolated localhost domain, lockstep to T_sim, metrics as offline plus the bag.
- ``cikan replay BAG [--rate R | --fast] [--wait-subscribers N]``: republish a bag with /clock.
- Nodes by hand, colcon and ``ros2 launch``: docs/ros_graph.md, sections "Running the nodes by hand" (a
  tested recipe) and "colcon and ROS 2 launch"; ``<node> --help`` lists a node's parameters.
- Executor: EventsExecutor (measured faster; ``CIKAN_ROS_EXECUTOR=single`` for the other).
- Gain tables are cached in ``$CIKAN_CACHE_DIR`` or ``~/.cache/cikan_ros``.
"""

"""The ROS 2 side of cikan_ros: message conversions, topics and QoS, nodes' shared plumbing,
the MCAP recorder, replay and the graph launcher.

Everything that imports rclpy lives here (and in the node packages ``sim_node``,
``governor_node``, ``controller_node``); the rest of the library runs without ROS.

Use:

- ``cikan mission [--governor NAME] [--seed N] [--bag DIR] [--json]``: the four nodes as separate
  processes on an isolated localhost domain, lockstep to T_sim, metrics as offline plus the bag.
- ``cikan replay BAG [--rate R | --fast] [--wait-subscribers N]``: republish a bag with /clock.
- Nodes by hand (one shell each, same ROS_DOMAIN_ID, ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST):
  ``recorder_node --ros-args -p recorder.bag:=bags/run -p graph.peers:="[sim,governor,controller,recorder]"``,
  ``governor_node --ros-args -p governor.name:=cikan``, ``controller_node``, ``sim_node``;
  every node also takes ``--params-file config/cikan.yaml``. With a ROS 2 Jazzy install:
  ``colcon build`` then ``ros2 run cikan_ros sim_node`` (package.xml, setup.cfg, setup.py).
- Executor: EventsExecutor (measured faster; ``CIKAN_ROS_EXECUTOR=single`` for the other).
- Gain tables are cached in ``$CIKAN_CACHE_DIR`` or ``~/.cache/cikan_ros``.
"""

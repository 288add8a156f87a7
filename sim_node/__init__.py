"""sim_node: the simulator of the cikan_ros graph (chief and deputy, /clock, lockstep master)."""

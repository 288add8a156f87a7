"""governor_node: the Time Shift Governor of the cikan_ros graph (conventional or learned)."""

"""controller_node: the saturated FTRE controller of the cikan_ros graph."""

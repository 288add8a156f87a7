"""governor_node itself, flying a conventional TSG that raises on every update from time T on
(argument 1, seconds since the mission epoch), for the ROS user-path tests: what the node does
when its governor raises mid-mission (it holds the last verified shift)."""

import sys

import governor_node.node as node
from cikan_ros.registry import make_governor

FAILING_FROM_S = float(sys.argv[1])


class RaisingGovernor:
    """The conventional TSG, except that every update at t >= FAILING_FROM_S raises."""

    def __init__(self, inner) -> None:
        self.inner = inner
        self.name = "raising"
        self.predictor = inner.predictor
        self.anchor = inner.anchor

    def initial(self, x_d, x_c, t):
        return self.inner.initial(x_d, x_c, t)

    def update(self, x_d, x_c, t, tau_prev):
        if t >= FAILING_FROM_S:
            raise RuntimeError(f"raising governor: failing as planned at t = {t:g} s")
        return self.inner.update(x_d, x_c, t, tau_prev)


# governor.name is the launcher's "exec:..." label: the node flies this governor whatever it says.
node.make_governor = lambda _name, cfg, predictor=None: RaisingGovernor(make_governor("conventional", cfg,
                                                                                      predictor))

if __name__ == "__main__":
    sys.exit(node.main(sys.argv[:1] + sys.argv[2:]))

"""A separate subscriber process for the replay tests: one node, reliable KEEP_ALL (or KEEP_LAST
depth N) subscriptions to the graph's topics (all, or the comma-separated TOPICS); prints "ready",
then, once it has the expected number of /tsg/time_shift messages (or after the timeout), one JSON
line: counts per topic and the stamps (ns) of /tsg/time_shift in arrival order.

usage: python replay_sink.py EXPECTED_SHIFTS TIMEOUT_S [DEPTH [TOPICS]]   (DEPTH 0 = KEEP_ALL)
"""

from __future__ import annotations

import json
import sys


def main() -> int:
    import rclpy
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    from rclpy.task import Future

    from cikan_ros.ros.graph_spec import TIME_SHIFT, TOPIC_TYPES, message_class

    expected, timeout = int(sys.argv[1]), float(sys.argv[2])
    depth = int(sys.argv[3]) if len(sys.argv) > 3 else 0
    topics = sys.argv[4].split(",") if len(sys.argv) > 4 else list(TOPIC_TYPES)
    qos = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE) if depth == 0 \
        else QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=ReliabilityPolicy.RELIABLE)
    rclpy.init()
    node = rclpy.create_node("replay_sink")
    counts = {t: 0 for t in topics}
    stamps: list[int] = []
    done = Future()

    def on(topic: str, msg: object) -> None:
        counts[topic] += 1
        if topic == TIME_SHIFT:
            stamps.append(msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec)
            if len(stamps) >= expected:
                done.set_result(True)

    for topic in topics:
        node.create_subscription(message_class(TOPIC_TYPES[topic]), topic, lambda m, t=topic: on(t, m), qos)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    print("ready", flush=True)
    try:
        executor.spin_until_future_complete(done, timeout_sec=timeout)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        print(json.dumps({"counts": counts, "shift_stamps": stamps}), flush=True)
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())

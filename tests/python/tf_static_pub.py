"""Publishes a bag's /tf_static as a robot's static transform publisher does: every transform of the bag's
/tf_static messages in one tf2_msgs/TFMessage, reliable and transient local (late subscribers get it), then
spins until stdin closes or SIGINT. Prints ``tf_static published: N transforms`` once it has published.

    tf_static_pub.py --bag DIR

Run by test_node_replay.py --tf-static in the replay's domain (loopback only, as every process there).
"""

import argparse
import sys
import threading
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import dcloc_testlib as tl


def bag_transforms(bag: Path):
    from rclpy.serialization import deserialize_message
    from rosbags.rosbag2 import Reader
    from tf2_msgs.msg import TFMessage

    out = TFMessage()
    with Reader(bag) as reader:
        conns = [c for c in reader.connections if c.topic == "/tf_static"]
        for _, _, raw in reader.messages(connections=conns):
            out.transforms.extend(deserialize_message(bytes(raw), TFMessage).transforms)
    return out


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--bag", required=True, type=Path)
    a = ap.parse_args()
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    from tf2_msgs.msg import TFMessage

    msg = bag_transforms(a.bag)
    if not msg.transforms:
        raise SystemExit(f"{a.bag}: no /tf_static transforms")
    with tl.RclpySession("dc_loc_tf_static") as rs:
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
        pub = rs.node.create_publisher(TFMessage, "/tf_static", qos)
        pub.publish(msg)
        print(f"tf_static published: {len(msg.transforms)} transforms", flush=True)
        closed = threading.Event()
        threading.Thread(target=lambda: (sys.stdin.read(), closed.set()), daemon=True).start()
        while not closed.is_set():
            rs.executor.spin_once(timeout_sec=0.1)
    return 0


if __name__ == "__main__":
    tl.run_main(main)

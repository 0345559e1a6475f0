"""Replays a simulated drive into the dc_loc node with its back-end outputs on, as real ROS 2 users see them,
with examples/backend_gtsam.py running as a back end. Run by tests/backend.rs with the venv's interpreter:

    test_backend_replay.py --node BIN --bag DIR --out RESULT.json --backend-out TRAJ.csv [--rate R]
                           [--pose-graph-topic T] [--lio-sam-topic T] [-- NODE ARGS...]

1. Reserves a ROS domain id of its own; everything stays on loopback (dcloc_testlib).
2. Starts the node (``BIN --ros-args NODE ARGS``; the Rust test turns the outputs on there) and the GTSAM
   back end (``examples/backend_gtsam.py --out TRAJ.csv``), waits for both.
3. rclpy subscribers: ``dc_loc/msg/LoopClosure`` on ``/dc_loc/loop_closures``,
   ``pose_graph_tools_msgs/msg/PoseGraph`` (reliable, transient local) and ``std_msgs/Float64MultiArray``
   (reliable, volatile) on the two back-end topics, ``/diagnostics``; rclpy publishers for the bag's radar
   and odometry topics, each matched by the node and (odometry) the back end before the replay starts.
4. Publishes the bag's messages (raw CDR, original stamps) in log-time order at ``--rate`` times real time,
   waits until the node has processed everything and every subscriber has as many messages as the node
   published closures, then SIGINT to the node (exit 0 expected) and to the back end, which writes its
   optimised trajectory.
5. Writes RESULT.json: ``closures`` (dc_loc's ClosureRecord JSON objects), ``pose_graphs`` and
   ``lio_sam`` (the messages as plain values, in arrival order), ``node_exit``, ``backend_exit``,
   ``replay_seconds``, ``backend_trajectory`` (the path written). The checks are the Rust test's.
"""

import argparse
import json
import signal
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import dcloc_testlib as tl
from test_node_replay import read_bag, record

CLOSURES = "/dc_loc/loop_closures"
BACKEND = tl.REPO / "examples" / "backend_gtsam.py"


def qos(transient: bool):
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL if transient else DurabilityPolicy.VOLATILE)


def replay(rs, pubs, messages, rate: float) -> float:
    """Publishes ``messages`` at ``rate`` times real time (spinning meanwhile); returns the wall time."""
    start = time.monotonic()
    for t, topic, _, raw in messages:
        due = start + (t - messages[0][0]) * 1e-9 / rate
        while (left := due - time.monotonic()) > 0:
            rs.executor.spin_once(timeout_sec=min(left, 0.01))
        pubs[topic].publish(raw)
    return time.monotonic() - start


def run(a, messages, node, backend) -> dict:
    from diagnostic_msgs.msg import DiagnosticArray
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import PointCloud2
    from std_msgs.msg import Float64MultiArray

    from dc_loc.msg import LoopClosure
    from pose_graph_tools_msgs.msg import PoseGraph

    result = {}
    node.wait_for_line(lambda l: "running" in l, 30.0, "the node's running line")
    backend.wait_for_line(lambda l: "running" in l, 60.0, "the back end's running line")
    with tl.RclpySession("dc_loc_backend_replay") as rs:
        types = {"sensor_msgs/msg/PointCloud2": PointCloud2, "nav_msgs/msg/Odometry": Odometry}
        pubs = {}
        for _, topic, msgtype, _ in messages:
            if topic not in pubs:
                pubs[topic] = rs.node.create_publisher(types[msgtype], topic, qos(False))
        got = {"closures": [], "pose_graphs": [], "lio_sam": []}
        diag = {}
        rs.node.create_subscription(LoopClosure, CLOSURES, lambda m: got["closures"].append(record(m)),
                                    tl.rclpy_qos_loop_closure())
        pg = rs.node.create_subscription(PoseGraph, a.pose_graph_topic,
                                         lambda m: got["pose_graphs"].append(tl.to_plain(m)), qos(True))
        lio = rs.node.create_subscription(Float64MultiArray, a.lio_sam_topic,
                                          lambda m: got["lio_sam"].append(tl.to_plain(m)), qos(False))

        def on_diag(m):
            for st in m.status:
                for kv in st.values:
                    diag[f"{st.name}/{kv.key}"] = kv.value

        diag_sub = rs.node.create_subscription(DiagnosticArray, "/diagnostics", on_diag, 10)
        # The node reads every input; the back end reads the odometry too.
        for topic, p in pubs.items():
            rs.wait_for_subscriptions(p, 2 if topic == "/odom" else 1)
        for sub in (pg, lio, diag_sub):
            rs.wait_for_publishers(sub, 1)
        rs.spin_until(lambda: any(k.endswith(".publishers") for k in diag)
                      and all(int(v) >= 1 for k, v in diag.items() if k.endswith(".publishers")),
                      30.0, "the node's readers to match the publishers")
        result["replay_seconds"] = replay(rs, pubs, messages, a.rate)

        def done():
            closures = int(diag.get("dc_loc: processing/closures", -1))
            queued = (int(diag.get("dc_loc: processing/queue_depth", -1))
                      + int(diag.get("dc_loc: processing/held_for_order", -1)))
            received = sum(int(v) for k, v in diag.items() if k.endswith(".received"))
            return (received == len(messages) and queued == 0
                    and all(len(v) == closures for v in got.values()))

        rs.spin_until(done, 90.0, "the node to process everything and every subscriber to catch up")
        node.proc.send_signal(signal.SIGINT)
        result["node_exit"] = node.proc.wait(timeout=30)
        rs.spin_until(lambda: True, 0.5, "spin")
        result.update(got)
    # The back end optimises once more and writes its trajectory when interrupted, in well under a
    # second for these drives; the bound is for a back end that never exits.
    backend.proc.send_signal(signal.SIGINT)
    result["backend_exit"] = backend.proc.wait(timeout=60)
    result["backend_trajectory"] = str(a.backend_out)
    return result


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--node", required=True)
    ap.add_argument("--bag", required=True, type=Path)
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--backend-out", required=True, type=Path)
    ap.add_argument("--rate", type=float, default=5.0)
    ap.add_argument("--pose-graph-topic", default="/dc_loc/pose_graph")
    ap.add_argument("--lio-sam-topic", default="/lio_loop/loop_closure_detection")
    ap.add_argument("node_args", nargs="*")
    a = ap.parse_args()

    messages = read_bag(a.bag)
    reservation = tl.reserve_domain_id()
    tl.apply_loopback_env(reservation.domain_id)
    env = tl.loopback_env(reservation.domain_id)
    node = tl.ManagedProcess([a.node, "--ros-args", *a.node_args], env, name="dc_loc")
    backend = tl.ManagedProcess([sys.executable, str(BACKEND), "--odom", "/odom", "--closures", CLOSURES,
                                 "--out", str(a.backend_out)], env, name="backend_gtsam")
    try:
        result = run(a, messages, node, backend)
    finally:
        node.stop()
        backend.stop()
        reservation.release()
    a.out.write_text(json.dumps(result))
    print(f"backend replay: {len(messages)} messages in {result['replay_seconds']:.1f} s, "
          f"{len(result['closures'])} closures, {len(result['pose_graphs'])} pose graphs, "
          f"{len(result['lio_sam'])} LIO-SAM pairs, node exit {result['node_exit']}, "
          f"back end exit {result['backend_exit']}")
    return 0


if __name__ == "__main__":
    tl.run_main(main)

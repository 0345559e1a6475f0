"""dc_loc/msg/LoopClosure from rclpy reaches rclpy and Cyclone DDS subscribers with every field intact.

Run by tests/python_msg.rs as ``<repo>/.venv/bin/python tests/python/test_loop_closure_msg.py``; exits 0
when every check passed, 1 otherwise (the failing check and the first differing field on stderr).

Checks
1. Without DDS: rclpy's CDR (``serialize_message``, Fast DDS type support generated from
   msg/LoopClosure.msg) and Cyclone's (XCDR1, the hand-written IDL types of dcloc_testlib) have the same
   encapsulation header and length, and each side decodes the other's bytes to exactly the values sent.
2. Over DDS (loopback, a domain id of this test's own), one process per participant:
   an rclpy publisher (reliable, transient-local, keep last 100) waits until it has matched two early
   subscribers, an rclpy one typed with ``dc_loc.msg.LoopClosure`` and a Cyclone one, then publishes
   COUNT messages; both get them all, in order, equal to what was sent. Then two late subscribers (rclpy,
   Cyclone) start after the publishing and get the whole history through transient-local durability.
3. Names and QoS as the subscribers discover them: the Cyclone side sees the writer on DDS topic
   ``rt/<topic>`` with type ``dc_loc::msg::dds_::LoopClosure_`` and reliable/transient-local QoS; the rclpy
   graph lists the publisher with type ``dc_loc/msg/LoopClosure`` and the same QoS.

Each message has distinctive values in every field (unsigned values above the signed range, negative
seconds, a non-ASCII frame id, 36 distinct covariance entries), so a swapped, truncated or misaligned
field shows up as a difference.
"""

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import dcloc_testlib as tl

TOPIC = "/dc_loc_test/loop_closures"
ROS_TYPE = "dc_loc/msg/LoopClosure"
COUNT = 8
TIMEOUT_S = 30.0


def expected_message(i: int) -> dict:
    """Message ``i`` as plain values; every field distinct from the others and from message ``i + 1``."""

    def pose(k: float) -> dict:
        return {
            "position": {"x": 1.5 + k + i, "y": -2.25 * (k + 1), "z": 1e-300 * (k + 1)},
            "orientation": {"x": 0.125 + k, "y": -0.25 - i, "z": 0.375 * (k + 2), "w": 0.5 + 1e-9 * i},
        }

    return {
        "header": {"stamp": {"sec": 1_700_000_000 + i, "nanosec": 123_456_789 + i},
                   "frame_id": f"base_link_{i}_ß"},
        "query_id": 2**64 - 1 - i,
        "match_id": 2**40 + 17 * i,
        "query_robot": -(2**31) + i,
        "match_robot": 2**31 - 1 - 3 * i,
        "query_stamp": {"sec": -(i + 1), "nanosec": 999_999_999 - i},
        "match_stamp": {"sec": 2**31 - 1 - i, "nanosec": i},
        "query_odom_pose": pose(10.0),
        "match_odom_pose": pose(20.0),
        "relative_pose": {"pose": pose(30.0), "covariance": [k + 0.5 + 0.001 * i for k in range(36)]},
        "inliers": 2**32 - 1 - i,
        "score": 0.1 + i / 3.0,
    }


def first_difference(got, want, path: str = "msg"):
    """Path and values of the first difference between two plain values, or None if equal."""
    if isinstance(want, dict) and isinstance(got, dict):
        for key in want.keys() | got.keys():
            diff = first_difference(got.get(key), want.get(key), f"{path}.{key}")
            if diff:
                return diff
        return None
    if isinstance(want, list) and isinstance(got, list):
        if len(got) != len(want):
            return f"{path}: length {len(got)}, expected {len(want)}"
        for k, (g, w) in enumerate(zip(got, want, strict=True)):
            diff = first_difference(g, w, f"{path}[{k}]")
            if diff:
                return diff
        return None
    if type(got) is not type(want) or got != want:
        return f"{path}: got {got!r}, expected {want!r}"
    return None


def emit(event: str, **data) -> None:
    """One JSON line on stdout for the orchestrating process."""
    print(json.dumps({"event": event, **data}), flush=True)


# ---- roles (child processes; environment from tl.loopback_env) -------------------------------------------


def role_publisher(subscribers: int) -> int:
    from dc_loc.msg import LoopClosure

    with tl.RclpySession("lc_test_publisher") as session:
        publisher = session.node.create_publisher(LoopClosure, TOPIC, tl.rclpy_qos_loop_closure())
        emit("ready")
        session.wait_for_subscriptions(publisher, subscribers, TIMEOUT_S)
        for i in range(COUNT):
            publisher.publish(tl.fill_rclpy(LoopClosure, expected_message(i)))
        emit("published", count=COUNT)
        # Keep the writer and its history alive for the late subscribers.
        session.spin_until(tl.stdin_eof().is_set, 600.0, "stdin to close")
    return 0


def role_rclpy_subscriber(tag: str) -> int:
    from dc_loc.msg import LoopClosure

    received = []
    with tl.RclpySession(f"lc_test_rclpy_{tag}") as session:
        session.node.create_subscription(
            LoopClosure, TOPIC, lambda msg: received.append(tl.to_plain(msg)), tl.rclpy_qos_loop_closure())
        emit("ready")
        session.spin_until(lambda: len(received) >= COUNT, TIMEOUT_S, f"{COUNT} loop closures")
        session.spin_until(lambda: len(session.node.get_publishers_info_by_topic(TOPIC)) >= 1, TIMEOUT_S,
                           "the publisher in the ROS graph")
        info = session.node.get_publishers_info_by_topic(TOPIC)[0]
        qos = info.qos_profile
        emit("received", messages=received, publisher={
            "node_name": info.node_name,
            "topic_type": info.topic_type,
            "reliability": qos.reliability.name,
            "durability": qos.durability.name,
        })
    return 0


def role_cyclone_subscriber(tag: str) -> int:
    received = []
    with tl.CycloneSession() as session:
        publications = session.publications()
        reader = session.reader(TOPIC, tl.LoopClosure, tl.cyclone_qos_loop_closure())
        emit("ready")

        def take_all() -> bool:
            received.extend(tl.to_plain(sample) for sample in reader.take(N=COUNT + 10))
            return len(received) >= COUNT

        tl.wait_until(take_all, TIMEOUT_S, f"{COUNT} loop closures ({tag})")
        dds_topic = tl.dds_topic_name(TOPIC)
        tl.wait_until(lambda: bool(publications.on_topic(dds_topic)), TIMEOUT_S, f"a publication on {dds_topic}")
        found = publications.on_topic(dds_topic)[0]
        emit("received", messages=received, publication={
            "topic_name": found.topic_name,
            "type_name": found.type_name,
            "qos": str(found.qos),
        })
    return 0


# ---- the checks (orchestrating process) ------------------------------------------------------------------


class Checks:
    def __init__(self) -> None:
        self.passed = 0
        self.failed = 0

    def check(self, ok: bool, what: str, detail: str = "") -> None:
        if ok:
            self.passed += 1
            print(f"ok: {what}", flush=True)
        else:
            self.failed += 1
            print(f"FAILED: {what}: {detail}", file=sys.stderr, flush=True)

    def messages(self, got: list, who: str) -> None:
        want = [expected_message(i) for i in range(COUNT)]
        self.check(got == want, f"{who} received all {COUNT} loop closures intact and in order",
                   first_difference(got, want, "messages") or "")


def check_serialization(checks: Checks) -> None:
    """Check 1: the two vendors' CDR encodings agree, byte for byte (no DDS involved)."""
    from dc_loc.msg import LoopClosure
    from rclpy.serialization import deserialize_message, serialize_message

    for i in range(COUNT):
        want = expected_message(i)
        rclpy_bytes = serialize_message(tl.fill_rclpy(LoopClosure, want))
        cyclone_bytes = tl.fill_cyclone(tl.LoopClosure, want).serialize(use_version_2=False)
        # Not byte-for-byte: Fast DDS leaves alignment padding uninitialized (Cyclone writes zeros), so
        # the layouts are compared through each side decoding the other's bytes, field by field.
        checks.check(len(rclpy_bytes) == len(cyclone_bytes) and rclpy_bytes[:4] == cyclone_bytes[:4],
                     f"message {i}: rclpy and Cyclone CDR have the same header and length",
                     f"{rclpy_bytes[:4].hex()} {len(rclpy_bytes)} vs {cyclone_bytes[:4].hex()} {len(cyclone_bytes)}")
        from_rclpy = tl.to_plain(tl.LoopClosure.deserialize(rclpy_bytes))
        checks.check(from_rclpy == want, f"message {i}: Cyclone decodes rclpy's bytes",
                     first_difference(from_rclpy, want) or "")
        from_cyclone = tl.to_plain(deserialize_message(cyclone_bytes, LoopClosure))
        checks.check(from_cyclone == want, f"message {i}: rclpy decodes Cyclone's bytes",
                     first_difference(from_cyclone, want) or "")


def start(role: str, env: dict, *args: str) -> tl.ManagedProcess:
    argv = [sys.executable, str(Path(__file__).resolve()), "--role", role, *args]
    return tl.ManagedProcess(argv, env, name=f"{role} {' '.join(args)}".strip())


def event(child: tl.ManagedProcess, name: str) -> dict:
    line = child.wait_for_line(lambda s: s.startswith("{") and json.loads(s).get("event") == name,
                               TIMEOUT_S + 10.0, f"event {name!r}")
    return json.loads(line)


def check_received(checks: Checks, child: tl.ManagedProcess, vendor: str, who: str) -> None:
    """Checks 2 and 3 for one subscriber process."""
    result = event(child, "received")
    checks.messages(result["messages"], who)
    if vendor == "cyclone":
        publication = result["publication"]
        checks.check(publication["type_name"] == tl.dds_type_name(ROS_TYPE),
                     f"{who} sees DDS type {tl.dds_type_name(ROS_TYPE)}", str(publication))
        checks.check(publication["topic_name"] == tl.dds_topic_name(TOPIC),
                     f"{who} sees DDS topic {tl.dds_topic_name(TOPIC)}", str(publication))
        checks.check("Reliable" in publication["qos"] and "TransientLocal" in publication["qos"],
                     f"{who} sees a reliable, transient-local writer", publication["qos"])
        print(f"  writer as discovered by Cyclone: {publication}", flush=True)
    else:
        publisher = result["publisher"]
        checks.check(publisher["topic_type"] == ROS_TYPE, f"{who} sees ROS type {ROS_TYPE}", str(publisher))
        checks.check((publisher["reliability"], publisher["durability"]) == ("RELIABLE", "TRANSIENT_LOCAL"),
                     f"{who} sees a reliable, transient-local publisher", str(publisher))
        print(f"  publisher as listed by the rclpy graph: {publisher}", flush=True)


def check_over_dds(checks: Checks, domain_id: int) -> None:
    """Checks 2 and 3: early and late subscribers of both vendors."""
    env = tl.loopback_env(domain_id)
    children: list[tl.ManagedProcess] = []
    try:
        early = [start("rclpy-sub", env, "--tag", "early"), start("cyclone-sub", env, "--tag", "early")]
        children += early
        for child in early:
            event(child, "ready")
        publisher = start("publisher", env, "--subscribers", str(len(early)))
        children.append(publisher)
        event(publisher, "published")
        check_received(checks, early[0], "rclpy", "early rclpy subscriber")
        check_received(checks, early[1], "cyclone", "early Cyclone subscriber")

        # Started only now: everything was published before these subscribers existed.
        late = [start("rclpy-sub", env, "--tag", "late"), start("cyclone-sub", env, "--tag", "late")]
        children += late
        check_received(checks, late[0], "rclpy", "late rclpy subscriber (transient-local history)")
        check_received(checks, late[1], "cyclone", "late Cyclone subscriber (transient-local history)")
    finally:
        codes = [(child.name, child.stop()) for child in children]
    for name, code in codes:
        checks.check(code == 0, f"{name} exited cleanly", f"exit code {code}")


def orchestrate() -> int:
    checks = Checks()
    check_serialization(checks)
    with tl.reserve_domain_id() as reservation:
        print(f"ROS domain id {reservation.domain_id}, topic {TOPIC}", flush=True)
        check_over_dds(checks, reservation.domain_id)
    print(f"{checks.passed} passed, {checks.failed} failed", flush=True)
    return 0 if checks.failed == 0 else 1


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--role", choices=["publisher", "rclpy-sub", "cyclone-sub"])
    parser.add_argument("--tag", default="")
    parser.add_argument("--subscribers", type=int, default=1)
    args = parser.parse_args()
    if args.role == "publisher":
        return role_publisher(args.subscribers)
    if args.role == "rclpy-sub":
        return role_rclpy_subscriber(args.tag)
    if args.role == "cyclone-sub":
        return role_cyclone_subscriber(args.tag)
    return orchestrate()


if __name__ == "__main__":
    tl.run_main(main)

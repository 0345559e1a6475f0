"""The dc_loc node's parameters, namespace and remapping as a ROS 2 user sees them (run by tests/node.rs).

    test_node_params.py --node BIN --params FILE

Starts ``BIN --ros-args --params-file <own file> --params-file FILE -p keyframe.distance:=6.0
-r __ns:=/car1 -r __node:=loc -r /odom:=/wheel/odom`` on loopback with a domain id of its own, then checks
with rclpy:
1. the graph has node ``loc`` in namespace ``/car1``; it subscribes ``/wheel/odom`` (nav_msgs/msg/Odometry)
   and publishes ``/car1/loc/loop_closures`` (dc_loc/msg/LoopClosure), ``/car1/loc/markers``,
   ``/car1/loc/submap``, ``/diagnostics``;
2. ``get_parameters`` (what ``ros2 param get`` calls): the ``-p`` override, the own file's ``/car1/loc``
   section, the ``/**`` wildcard, defaults, ``use_sim_time``;
3. ``set_parameters`` of a running node: a structural parameter (``submap.size``) is refused and keeps its
   value, an out-of-range gate (``loop.search_radius`` -1) is refused naming it, a valid gate and the log
   level change (``get_parameters`` shows the new values);
   ``/rosout`` (rcl_interfaces/Log) carries the node's log, under the logger name ``car1.loc``;
4. SIGINT ends the node with exit code 0;
5. with ``-p use_sim_time:=true`` the node stamps its diagnostics with the ``/clock`` time an rclpy
   publisher sends (rosgraph_msgs/Clock).
Prints "params: all checks passed" and exits 0, or names the failed check and exits 1.
"""

import argparse
import signal
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import dcloc_testlib as tl

OWN_PARAMS = """\
/**:
  ros__parameters:
    submap:
      max_span: 2.5
/car1/loc:
  ros__parameters:
    submap:
      size: 7
    keyframe:
      distance: 4.0
other_node:
  ros__parameters:
    submap:
      size: 99
"""


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--node", required=True)
    ap.add_argument("--params", required=True)
    a = ap.parse_args()

    from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
    from rcl_interfaces.srv import GetParameters, SetParameters

    failures = []

    def check(ok: bool, what: str) -> None:
        print(("ok   " if ok else "FAIL ") + what)
        if not ok:
            failures.append(what)

    with tempfile.TemporaryDirectory() as tmp, tl.reserve_domain_id() as res:
        own = Path(tmp) / "own.yaml"
        own.write_text(OWN_PARAMS)
        env = tl.loopback_env(res.domain_id)
        argv = [a.node, "--ros-args", "--params-file", str(own), "-p", "keyframe.distance:=6.0",
                "-r", "__ns:=/car1", "-r", "__node:=loc", "-r", "/odom:=/wheel/odom"]
        with tl.ManagedProcess(argv, env, name="dc_loc") as node, \
                tl.RclpySession("dc_loc_params_check", res.domain_id) as rs:
            node.wait_for_line(lambda l: "running" in l, 30.0, "the node's running line")
            rs.spin_until(lambda: ("loc", "/car1") in rs.node.get_node_names_and_namespaces(), 20.0,
                          "node /car1/loc in the graph")
            check(True, "node /car1/loc in the graph")
            rs.spin_until(lambda: rs.topic_types("/car1/loc/loop_closures") != [], 20.0,
                          "the loop closure topic")
            for topic, ty in [("/car1/loc/loop_closures", "dc_loc/msg/LoopClosure"),
                              ("/car1/loc/markers", "visualization_msgs/msg/MarkerArray"),
                              ("/car1/loc/submap", "sensor_msgs/msg/PointCloud2"),
                              ("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray")]:
                rs.spin_until(lambda: rs.node.get_publishers_info_by_topic(topic) != [], 20.0,
                              f"a publisher on {topic}")
                infos = rs.node.get_publishers_info_by_topic(topic)
                check(any(i.topic_type == ty for i in infos), f"{topic} published as {ty}")
            rs.spin_until(lambda: rs.node.get_subscriptions_info_by_topic("/wheel/odom") != [], 20.0,
                          "a subscription on /wheel/odom")
            subs = rs.node.get_subscriptions_info_by_topic("/wheel/odom")
            check(any(s.topic_type == "nav_msgs/msg/Odometry" for s in subs), "/odom remapped to /wheel/odom")
            check(rs.node.get_subscriptions_info_by_topic("/odom") == [], "nothing subscribes /odom")

            def call(srv_type, name, request):
                client = rs.node.create_client(srv_type, name)
                rs.spin_until(client.service_is_ready, 20.0, f"service {name}")
                future = client.call_async(request)
                rs.spin_until(future.done, 20.0, f"reply of {name}")
                return future.result()

            names = ["keyframe.distance", "submap.size", "submap.max_span", "loop.search_radius",
                     "radars.front.topic", "use_sim_time", "node.queue_size"]
            reply = call(GetParameters, "/car1/loc/get_parameters", GetParameters.Request(names=names))
            values = dict(zip(names, reply.values))
            check(values["keyframe.distance"].double_value == 6.0, "-p override wins over the file")
            check(values["submap.size"].type == ParameterType.PARAMETER_INTEGER
                  and values["submap.size"].integer_value == 7, "/car1/loc section of the file")
            check(values["submap.max_span"].double_value == 2.5, "/** section of the file")
            check(values["loop.search_radius"].double_value == 25.0, "default value")
            check(values["radars.front.topic"].string_value == "/radar/points", "string parameter")
            check(values["use_sim_time"].type == ParameterType.PARAMETER_BOOL
                  and not values["use_sim_time"].bool_value, "use_sim_time declared, false")
            check(values["node.queue_size"].integer_value == 2000, "node.queue_size default")

            from rcl_interfaces.msg import Log
            from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

            logs = []
            rs.node.create_subscription(
                Log, "/rosout", lambda m: logs.append(m),
                QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                           durability=DurabilityPolicy.VOLATILE))

            def set_param(name, value):
                if isinstance(value, float):
                    v = ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=value)
                elif isinstance(value, int):
                    v = ParameterValue(type=ParameterType.PARAMETER_INTEGER, integer_value=value)
                else:
                    v = ParameterValue(type=ParameterType.PARAMETER_STRING, string_value=value)
                req = SetParameters.Request(parameters=[Parameter(name=name, value=v)])
                return call(SetParameters, "/car1/loc/set_parameters", req).results[0]

            def get(name):
                return call(GetParameters, "/car1/loc/get_parameters",
                            GetParameters.Request(names=[name])).values[0]

            r = set_param("submap.size", 9)
            check(not r.successful and "restart" in r.reason, f"structural parameter refused: {r.reason}")
            check(get("submap.size").integer_value == 7, "submap.size unchanged after the refused set")
            r = set_param("loop.search_radius", -1.0)
            check(not r.successful and "loop.search_radius" in r.reason,
                  f"out-of-range gate refused naming it: {r.reason}")
            r = set_param("loop.search_radius", 22.0)
            check(r.successful, f"live gate accepted ({r.reason})")
            check(get("loop.search_radius").double_value == 22.0, "loop.search_radius now 22")
            r = set_param("node.log_level", "debug")
            check(r.successful, f"log level accepted ({r.reason})")
            rs.spin_until(lambda: any("loop.search_radius set to" in m.msg and m.name == "car1.loc" for m in logs),
                          20.0, "the parameter change on /rosout")
            entry = next(m for m in logs if "loop.search_radius set to" in m.msg)
            check(entry.level == 20 and entry.file.endswith(".rs") and entry.line > 0,
                  f"/rosout record: level {entry.level}, {entry.file}:{entry.line}, {entry.function}")

            node.proc.send_signal(signal.SIGINT)
            code = node.proc.wait(timeout=20)
            check(code == 0, f"SIGINT: exit code {code}")

        # use_sim_time: the outputs follow /clock (rosgraph_msgs/Clock).
        from builtin_interfaces.msg import Time
        from diagnostic_msgs.msg import DiagnosticArray
        from rosgraph_msgs.msg import Clock

        argv = [a.node, "--ros-args", "-p", "use_sim_time:=true", "-p", "node.diagnostics_period:=0.2"]
        with tl.ManagedProcess(argv, env, name="dc_loc") as node, \
                tl.RclpySession("dc_loc_clock_check", res.domain_id) as rs:
            node.wait_for_line(lambda l: "running" in l, 30.0, "the node's running line")
            stamps = []
            clock_pub = rs.node.create_publisher(Clock, "/clock", 10)
            diag_sub = rs.node.create_subscription(
                DiagnosticArray, "/diagnostics", lambda m: stamps.append((m.header.stamp.sec,
                                                                          m.header.stamp.nanosec)), 10)
            rs.wait_for_subscriptions(clock_pub, 1)
            rs.wait_for_publishers(diag_sub, 1)
            sim = (4242, 500_000_000)

            def clock_seen():
                clock_pub.publish(Clock(clock=Time(sec=sim[0], nanosec=sim[1])))
                return sim in stamps

            rs.spin_until(clock_seen, 20.0, "diagnostics stamped with the /clock time")
            check(True, "use_sim_time: /diagnostics stamped with /clock time")
            node.proc.send_signal(signal.SIGINT)
            code = node.proc.wait(timeout=20)
            check(code == 0, f"SIGINT (sim time): exit code {code}")
    if failures:
        print(f"params: {len(failures)} checks failed: {failures}")
        return 1
    print("params: all checks passed")
    return 0


if __name__ == "__main__":
    tl.run_main(main)

"""Support for dc_loc tests that act as real ROS 2 users: rclpy (Jazzy, Fast DDS) and cyclonedds-python.

Run with the venv's interpreter (``<repo>/.venv/bin/python``, made by ``tests/python/setup_venv.sh``).
Every DDS participant a test makes must go through this module, which keeps DDS on loopback: discovery
range LOCALHOST, a domain id of the test's own, Fast DDS bound to 127.0.0.1 (``fastdds_loopback.xml``),
Cyclone DDS on interface ``lo`` without multicast, peer 127.0.0.1 (``cyclonedds_loopback.xml``).

Entry points
- Domain and environment: ``reserve_domain_id()`` -> ``DomainReservation`` (an id of the test's own,
  held by a lock file), ``loopback_env(domain_id)`` (variables for child processes, e.g. the dc_loc node),
  ``apply_loopback_env(domain_id)`` (the same into this process), ``check_loopback_env()``.
- rclpy: ``RclpySession`` (own context, one node, an executor; ``spin_until``,
  ``wait_for_subscriptions``, ``wait_for_publishers``, clean ``close``), ``rclpy_qos_loop_closure()``,
  ``run_main`` (maps SIGINT/SIGTERM, i.e. ``ExternalShutdownException``/``KeyboardInterrupt``, to exit 130).
- Cyclone DDS: ``CycloneSession`` (domain with the loopback config, participant, ``reader``/``writer``,
  ``publications`` from the built-in discovery topic), ``wait_for_matched`` and the IDL types ``Time``,
  ``Header``, ``Point``, ``Quaternion``, ``Pose``, ``PoseWithCovariance``, ``LoopClosure`` (DDS type
  names as rmw uses them: ``dc_loc::msg::dds_::LoopClosure_``), ``cyclone_qos_loop_closure()`` (the
  QoS of ``rclpy_qos_loop_closure()``).
- Names: ``dds_topic_name('/x') == 'rt/x'``, ``dds_type_name('dc_loc/msg/LoopClosure')``.
- Messages: ``to_plain(msg)`` (rclpy or cyclone message -> nested dicts/lists/ints/floats/str, for exact
  comparison across vendors), ``fill_rclpy(cls, plain)`` and ``fill_cyclone(cls, plain)`` (the inverse).
- Processes: ``ManagedProcess`` (child with line-based waiting on its stdout and an orderly stop: stdin
  EOF, then SIGINT, SIGTERM, SIGKILL), ``stdin_eof()`` (the child's side of that request), ``wait_until``.

Waiting is always for a condition (matching, a line, a count) with a deadline, never a fixed sleep:
discovery on loopback takes 0.2 s to over 1 s.
"""

import dataclasses
import fcntl
import os
import queue
import signal
import subprocess
import sys
import threading
import time
import typing
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import array, float64, int32, uint32, uint64

HERE = Path(__file__).resolve().parent
REPO = HERE.parent.parent
FASTDDS_PROFILE = HERE / "fastdds_loopback.xml"
CYCLONEDDS_CONFIG = HERE / "cyclonedds_loopback.xml"

# ROS domain ids the tests reserve from. Kept at or below 101: on Linux the DDS ports of higher domains
# (7400 + 250 * id + ...) fall into the ephemeral port range, where any socket may already hold them.
DOMAIN_ID_MIN = 51
DOMAIN_ID_MAX = 101
DOMAIN_LOCK_DIR = Path(os.environ.get("DCLOC_DOMAIN_LOCK_DIR", "/tmp"))


# ---------------------------------------------------------------------------------------------------------
# Domain id and environment
# ---------------------------------------------------------------------------------------------------------


@dataclass
class DomainReservation:
    """A ROS domain id reserved for this process: held while ``lock_file`` stays open."""

    domain_id: int
    lock_file: Any

    def release(self) -> None:
        """Releases the id (also happens when the process exits)."""
        if self.lock_file is not None:
            self.lock_file.close()
            self.lock_file = None

    def __enter__(self) -> "DomainReservation":
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


def reserve_domain_id() -> DomainReservation:
    """Reserves a domain id in [DOMAIN_ID_MIN, DOMAIN_ID_MAX] that no other test process holds.

    Each id has a lock file ``$DCLOC_DOMAIN_LOCK_DIR/dc_loc-ros-domain-<id>.lock`` (default /tmp) taken with
    a non-blocking ``flock``; the search starts at an offset derived from the process id. Any process may
    take part in this protocol (a Rust test can flock the same files). The lock is not inherited by
    children started with ``ManagedProcess``/``subprocess`` (close_fds), so keep the reservation in the
    process that outlives them.
    """
    count = DOMAIN_ID_MAX - DOMAIN_ID_MIN + 1
    start = os.getpid() % count
    DOMAIN_LOCK_DIR.mkdir(parents=True, exist_ok=True)
    for k in range(count):
        domain_id = DOMAIN_ID_MIN + (start + k) % count
        f = open(DOMAIN_LOCK_DIR / f"dc_loc-ros-domain-{domain_id}.lock", "a")
        try:
            fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            f.close()
            continue
        return DomainReservation(domain_id, f)
    raise RuntimeError(f"all ROS domain ids {DOMAIN_ID_MIN}..{DOMAIN_ID_MAX} are held by other tests")


def loopback_env(domain_id: int, base: dict | None = None) -> dict:
    """Environment for a process that may start DDS (rclpy, cyclonedds-python, the dc_loc node).

    Starts from ``base`` (default: this process's environment) and sets the domain id, discovery range
    LOCALHOST, the Fast DDS loopback profile and the Cyclone loopback config; removes what would widen
    discovery (static peers, discovery server, the deprecated ROS_LOCALHOST_ONLY) or bypass the profile.
    """
    if not 0 <= domain_id <= 232:
        raise ValueError(f"ROS domain id {domain_id} out of 0..232")
    env = dict(os.environ if base is None else base)
    for var in (
        "ROS_LOCALHOST_ONLY",
        "ROS_STATIC_PEERS",
        "ROS_DISCOVERY_SERVER",
        "ROS_SUPER_CLIENT",
        "RMW_FASTRTPS_USE_QOS_FROM_XML",
        "FASTDDS_ENVIRONMENT_FILE",
    ):
        env.pop(var, None)
    env.update(
        ROS_DOMAIN_ID=str(domain_id),
        ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
        RMW_IMPLEMENTATION="rmw_fastrtps_cpp",
        FASTRTPS_DEFAULT_PROFILES_FILE=str(FASTDDS_PROFILE),
        FASTDDS_DEFAULT_PROFILES_FILE=str(FASTDDS_PROFILE),
        CYCLONEDDS_URI=CYCLONEDDS_CONFIG.as_uri(),
    )
    return env


def apply_loopback_env(domain_id: int) -> None:
    """Puts ``loopback_env(domain_id)`` into this process (before any DDS participant is made)."""
    env = loopback_env(domain_id)
    for var in set(os.environ) - set(env):
        del os.environ[var]
    os.environ.update(env)


def check_loopback_env() -> int:
    """Returns ROS_DOMAIN_ID after checking this process's environment keeps DDS on loopback.

    Raises RuntimeError naming the offending variable otherwise: called before every participant made
    here, so that a test cannot start DDS without the loopback settings, not even once.
    """
    expected = loopback_env(0)
    for var in ("ROS_AUTOMATIC_DISCOVERY_RANGE", "RMW_IMPLEMENTATION", "FASTRTPS_DEFAULT_PROFILES_FILE",
                "CYCLONEDDS_URI"):
        if os.environ.get(var) != expected[var]:
            raise RuntimeError(f"{var}={os.environ.get(var)!r}, expected {expected[var]!r}: "
                               "use apply_loopback_env()/loopback_env() before starting DDS")
    for var in ("ROS_LOCALHOST_ONLY", "ROS_STATIC_PEERS", "ROS_DISCOVERY_SERVER"):
        if os.environ.get(var):
            raise RuntimeError(f"{var} is set: it would change discovery; use loopback_env()")
    try:
        domain_id = int(os.environ["ROS_DOMAIN_ID"])
    except (KeyError, ValueError):
        raise RuntimeError("ROS_DOMAIN_ID unset or not an integer: use reserve_domain_id()") from None
    if not 0 <= domain_id <= 232:
        raise RuntimeError(f"ROS_DOMAIN_ID={domain_id} out of 0..232")
    return domain_id


def dds_topic_name(ros_topic: str) -> str:
    """DDS topic of a ROS topic as rmw names it: '/a/b' -> 'rt/a/b' (the name must be absolute)."""
    if not ros_topic.startswith("/"):
        raise ValueError(f"ROS topic {ros_topic!r} is not absolute")
    return "rt" + ros_topic


def dds_type_name(ros_type: str) -> str:
    """DDS type of a ROS message type as rmw names it: 'pkg/msg/Name' -> 'pkg::msg::dds_::Name_'."""
    pkg, kind, name = ros_type.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"


# ---------------------------------------------------------------------------------------------------------
# Waiting and child processes
# ---------------------------------------------------------------------------------------------------------


def wait_until(predicate: Callable[[], bool], timeout: float, what: str, poll: float = 0.02,
               step: Callable[[float], None] | None = None) -> None:
    """Returns once ``predicate()`` holds; raises TimeoutError naming ``what`` after ``timeout`` s.

    ``step(seconds)`` is called between polls (e.g. to spin an executor); default: sleep ``poll``.
    """
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise TimeoutError(f"timed out after {timeout:.1f} s waiting for {what}")
        if step is None:
            time.sleep(poll)
        else:
            step(poll)


class ManagedProcess:
    """A child process whose stdout lines are collected by a thread, to be waited on with deadlines.

    stderr goes to this process's stderr (so it shows in the test's output); stdin is a pipe: closing it
    (``stop``) is the polite request to finish. Use as a context manager to always stop the child.
    """

    def __init__(self, argv: Sequence[str], env: dict, name: str | None = None,
                 cwd: Path | None = None) -> None:
        if env.get("ROS_AUTOMATIC_DISCOVERY_RANGE") != "LOCALHOST" or "ROS_DOMAIN_ID" not in env:
            raise RuntimeError("child environment must come from loopback_env()")
        self.name = name or Path(argv[0]).name
        self.lines: queue.Queue[str | None] = queue.Queue()
        self.seen: list[str] = []
        self.proc = subprocess.Popen(
            list(argv), env=env, cwd=cwd, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
            stderr=None, text=True, bufsize=1, close_fds=True)
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.put(line.rstrip("\n"))
        self.lines.put(None)

    def wait_for_line(self, predicate: Callable[[str], bool], timeout: float, what: str) -> str:
        """Returns the next stdout line satisfying ``predicate`` (earlier lines are kept in ``seen``)."""
        deadline = time.monotonic() + timeout
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError(f"{self.name}: timed out after {timeout:.1f} s waiting for {what}; "
                                   f"stdout so far: {self.seen[-20:]}")
            try:
                line = self.lines.get(timeout=left)
            except queue.Empty:
                continue
            if line is None:
                self.lines.put(None)  # keep reporting EOF
                code = self.proc.wait()
                raise RuntimeError(f"{self.name} exited with {code} before {what}; stdout: {self.seen[-20:]}")
            self.seen.append(line)
            if predicate(line):
                return line

    def stop(self, timeout: float = 10.0) -> int:
        """Asks the child to finish (stdin EOF, then SIGINT, SIGTERM, SIGKILL) and returns its exit code."""
        if self.proc.poll() is None and self.proc.stdin is not None:
            try:
                self.proc.stdin.close()
            except OSError:
                pass
        for sig in (None, signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
            if sig is not None and self.proc.poll() is None:
                self.proc.send_signal(sig)
            try:
                return self.proc.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                continue
        return self.proc.wait()

    def __enter__(self) -> "ManagedProcess":
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


_stdin_eof: threading.Event | None = None


def stdin_eof() -> threading.Event:
    """An event set once stdin closes (how ``ManagedProcess.stop`` asks a child to finish), read by a
    daemon thread, so that a child can keep spinning meanwhile: ``session.spin_until(stdin_eof().is_set,
    ...)``."""
    global _stdin_eof
    if _stdin_eof is None:
        _stdin_eof = threading.Event()

        def drain(event: threading.Event) -> None:
            for _ in sys.stdin:
                pass
            event.set()

        threading.Thread(target=drain, args=(_stdin_eof,), daemon=True).start()
    return _stdin_eof


def run_main(main: Callable[[], int]) -> None:
    """Runs ``main`` and exits with its code; SIGINT/SIGTERM (rclpy raises ``ExternalShutdownException``
    from spinning, Python ``KeyboardInterrupt``) exit 130 after ``main``'s own cleanup (its ``finally``/
    ``with`` blocks) has run, without a traceback."""
    from rclpy.executors import ExternalShutdownException

    def interrupt(signum: int, frame: object) -> None:
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, interrupt)
    try:
        code = main()
    except (KeyboardInterrupt, ExternalShutdownException):
        code = 130
    sys.stdout.flush()
    sys.exit(code)


# ---------------------------------------------------------------------------------------------------------
# rclpy
# ---------------------------------------------------------------------------------------------------------


def rclpy_qos_loop_closure(depth: int = 100):
    """rclpy QoS of dc_loc's loop closures: reliable, transient-local, keep last ``depth``, so that a back
    end starting late still gets the history."""
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)


class RclpySession:
    """An rclpy context of its own with one node and a single-threaded executor, on loopback.

    ``RclpySession('name', domain_id)`` applies ``loopback_env(domain_id)`` to this process first;
    ``RclpySession('name')`` requires the environment to be set already (children of ``ManagedProcess``).
    rclpy turns SIGINT/SIGTERM into a context shutdown: ``spin_until`` then raises
    ``ExternalShutdownException``; ``close`` (also on ``with`` exit) tolerates that state.
    """

    def __init__(self, node_name: str, domain_id: int | None = None, namespace: str = "/") -> None:
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor

        if domain_id is not None:
            apply_loopback_env(domain_id)
        self.domain_id = check_loopback_env()
        self.context = Context()
        rclpy.init(context=self.context, domain_id=self.domain_id)
        self.node = rclpy.create_node(node_name, namespace=namespace, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def spin_until(self, predicate: Callable[[], bool], timeout: float, what: str) -> None:
        """Spins the node (callbacks run) until ``predicate()`` holds; TimeoutError after ``timeout`` s."""
        wait_until(predicate, timeout, what, step=lambda t: self.executor.spin_once(timeout_sec=t))

    def wait_for_subscriptions(self, publisher: Any, count: int, timeout: float = 20.0) -> None:
        """Waits until ``publisher`` has matched at least ``count`` subscriptions (any DDS vendor)."""
        self.spin_until(lambda: publisher.get_subscription_count() >= count, timeout,
                        f"{count} subscription(s) on {publisher.topic_name}")

    def wait_for_publishers(self, subscription: Any, count: int, timeout: float = 20.0) -> None:
        """Waits until ``subscription`` has matched at least ``count`` publishers (any DDS vendor)."""
        self.spin_until(lambda: subscription.get_publisher_count() >= count, timeout,
                        f"{count} publisher(s) on {subscription.topic_name}")

    def topic_types(self, ros_topic: str) -> list[str]:
        """The ROS type names the graph lists for ``ros_topic`` (empty until discovered)."""
        return dict(self.node.get_topic_names_and_types()).get(ros_topic, [])

    def close(self) -> None:
        """Destroys the node and shuts the context down (idempotent, fine after a signal)."""
        if self.node is not None:
            self.executor.remove_node(self.node)
            self.node.destroy_node()
            self.node = None
            self.executor.shutdown(timeout_sec=1.0)
        self.context.try_shutdown()

    def __enter__(self) -> "RclpySession":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def fill_rclpy(cls: type, plain: dict) -> Any:
    """Builds an rclpy message of ``cls`` from nested dicts (as from ``to_plain``); missing keys keep
    their defaults, unknown keys raise KeyError."""
    msg = cls()
    fields = msg.get_fields_and_field_types()
    for key, value in plain.items():
        if key not in fields:
            raise KeyError(f"{cls.__name__} has no field {key!r}")
        if isinstance(value, dict):
            setattr(msg, key, fill_rclpy(type(getattr(msg, key)), value))
        else:
            setattr(msg, key, value)
    return msg


def fill_cyclone(cls: type, plain: dict) -> Any:
    """Builds a cyclone IDL object of ``cls`` (e.g. ``LoopClosure``) from nested dicts; missing keys keep
    their defaults, unknown keys raise KeyError."""
    hints = typing.get_type_hints(cls)
    values = {}
    for key, value in plain.items():
        if key not in hints:
            raise KeyError(f"{cls.__name__} has no field {key!r}")
        field_type = hints[key]
        if isinstance(value, dict):
            values[key] = fill_cyclone(field_type, value)
        elif isinstance(value, list):
            values[key] = list(value)
        else:
            values[key] = value
    return cls(**values)


def to_plain(msg: Any) -> Any:
    """An rclpy message or cyclone IDL object as nested dicts/lists of int, float, str (exact values)."""
    if hasattr(msg, "get_fields_and_field_types"):
        return {f: to_plain(getattr(msg, f)) for f in msg.get_fields_and_field_types()}
    if dataclasses.is_dataclass(msg):
        return {f.name: to_plain(getattr(msg, f.name)) for f in dataclasses.fields(msg)}
    if isinstance(msg, (str, bytes)):
        return msg
    if hasattr(msg, "tolist"):  # numpy arrays and scalars
        return msg.tolist()
    if isinstance(msg, Iterable):
        return [to_plain(x) for x in msg]
    return msg


# ---------------------------------------------------------------------------------------------------------
# Cyclone DDS (second vendor)
# ---------------------------------------------------------------------------------------------------------


@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    """builtin_interfaces/msg/Time."""

    sec: int32 = 0
    nanosec: uint32 = 0


@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    """std_msgs/msg/Header."""

    stamp: Time = dataclasses.field(default_factory=Time)
    frame_id: str = ""


@dataclass
class Point(IdlStruct, typename="geometry_msgs::msg::dds_::Point_"):
    """geometry_msgs/msg/Point."""

    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0


@dataclass
class Quaternion(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
    """geometry_msgs/msg/Quaternion (defaults to identity, as in ROS)."""

    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0
    w: float64 = 1.0


@dataclass
class Pose(IdlStruct, typename="geometry_msgs::msg::dds_::Pose_"):
    """geometry_msgs/msg/Pose."""

    position: Point = dataclasses.field(default_factory=Point)
    orientation: Quaternion = dataclasses.field(default_factory=Quaternion)


@dataclass
class PoseWithCovariance(IdlStruct, typename="geometry_msgs::msg::dds_::PoseWithCovariance_"):
    """geometry_msgs/msg/PoseWithCovariance (covariance row-major x y z rotx roty rotz)."""

    pose: Pose = dataclasses.field(default_factory=Pose)
    covariance: array[float64, 36] = dataclasses.field(default_factory=lambda: [0.0] * 36)


@dataclass
class LoopClosure(IdlStruct, typename="dc_loc::msg::dds_::LoopClosure_"):
    """dc_loc/msg/LoopClosure (msg/LoopClosure.msg), field order as in the .msg."""

    header: Header = dataclasses.field(default_factory=Header)
    query_id: uint64 = 0
    match_id: uint64 = 0
    query_robot: int32 = 0
    match_robot: int32 = 0
    query_stamp: Time = dataclasses.field(default_factory=Time)
    match_stamp: Time = dataclasses.field(default_factory=Time)
    query_odom_pose: Pose = dataclasses.field(default_factory=Pose)
    match_odom_pose: Pose = dataclasses.field(default_factory=Pose)
    relative_pose: PoseWithCovariance = dataclasses.field(default_factory=PoseWithCovariance)
    inliers: uint32 = 0
    score: float64 = 0.0


def cyclone_qos_loop_closure(depth: int = 100):
    """Cyclone QoS equal to ``rclpy_qos_loop_closure`` (reliable, transient-local, keep last ``depth``)."""
    from cyclonedds.core import Policy, Qos
    from cyclonedds.util import duration

    return Qos(Policy.Reliability.Reliable(max_blocking_time=duration(seconds=1)),
               Policy.Durability.TransientLocal, Policy.History.KeepLast(depth))


class CycloneSession:
    """A Cyclone DDS domain made with the loopback config, and one participant in it.

    ``CycloneSession(domain_id)`` applies ``loopback_env(domain_id)`` first; ``CycloneSession()`` requires
    it set already. The config is also passed explicitly to the domain, so it does not hinge on
    CYCLONEDDS_URI being read.
    """

    def __init__(self, domain_id: int | None = None) -> None:
        from cyclonedds.domain import Domain, DomainParticipant

        if domain_id is not None:
            apply_loopback_env(domain_id)
        self.domain_id = check_loopback_env()
        self.domain = Domain(self.domain_id, CYCLONEDDS_CONFIG.read_text())
        self.participant = DomainParticipant(self.domain_id)

    def reader(self, ros_topic: str, data_type: type, qos: Any = None):
        """A DataReader of ``data_type`` on the DDS topic of ``ros_topic`` ('rt' prefix added)."""
        from cyclonedds.sub import DataReader
        from cyclonedds.topic import Topic

        topic = Topic(self.participant, dds_topic_name(ros_topic), data_type)
        return DataReader(self.participant, topic, qos=qos)

    def writer(self, ros_topic: str, data_type: type, qos: Any = None):
        """A DataWriter of ``data_type`` on the DDS topic of ``ros_topic`` ('rt' prefix added)."""
        from cyclonedds.pub import DataWriter
        from cyclonedds.topic import Topic

        topic = Topic(self.participant, dds_topic_name(ros_topic), data_type)
        return DataWriter(self.participant, topic, qos=qos)

    def publications(self) -> "PublicationsReader":
        """A reader of the built-in DCPSPublication topic: what remote writers announce (topic and type
        name, QoS), as discovery delivers it."""
        return PublicationsReader(self.participant)

    def close(self) -> None:
        """Deletes the participant and the domain (idempotent)."""
        for name in ("participant", "domain"):
            entity = getattr(self, name, None)
            if entity is not None:
                entity.__del__()  # cyclonedds-python deletes the DDS entity here
                setattr(self, name, None)

    def __enter__(self) -> "CycloneSession":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class PublicationsReader:
    """Remote writers as discovered (built-in DCPSPublication topic), accumulated by ``poll``."""

    def __init__(self, participant: Any) -> None:
        from cyclonedds.builtin import BuiltinDataReader, BuiltinTopicDcpsPublication

        self._reader = BuiltinDataReader(participant, BuiltinTopicDcpsPublication)
        self.seen: list[Any] = []

    def poll(self) -> list[Any]:
        """Reads newly discovered publications (``DcpsEndpoint``: topic_name, type_name, qos, ...)."""
        self.seen.extend(self._reader.take(N=64))
        return self.seen

    def on_topic(self, dds_topic: str) -> list[Any]:
        """The publications seen so far on ``dds_topic`` (after ``poll``)."""
        self.poll()
        return [p for p in self.seen if p.topic_name == dds_topic]


def wait_for_matched(entity: Any, count: int, timeout: float = 20.0, what: str = "") -> None:
    """Waits until a cyclone DataReader (matched writers) or DataWriter (matched readers) has at least
    ``count`` matches."""
    if hasattr(entity, "get_subscription_matched_status"):
        status = entity.get_subscription_matched_status
    else:
        status = entity.get_publication_matched_status
    wait_until(lambda: status().current_count >= count, timeout, what or f"{count} DDS match(es)")

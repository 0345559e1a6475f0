"""A Cyclone DDS participant (Debian's Cyclone DDS 0.10 with its DDS Security plugins) talking to dc_loc.

Run with the interpreter of the secured Cyclone venv (``tests/python/setup_cyclone_security.sh``): the
cyclonedds binding there uses the system's libddsc, which loads the plugins named in the configuration.

    cyclone_secured_peer.py --domain ID [--enclave DIR] [--cloud-topic /radar/points]
                            [--cloud-frame FRAME] [--bad-stamp] [--rate HZ] [--seconds S]

With ``--enclave`` (an sros2 enclave directory: identity_ca.cert.pem, cert.pem, key.pem,
permissions_ca.cert.pem, governance.p7s, permissions.p7s) the participant is secured with it; without, it
is an ordinary unsecured participant. Either way it subscribes to the node's loop closures
(``--closures``, reliable, transient-local) and to ``/diagnostics``, and with ``--cloud-topic`` publishes
an empty PointCloud2 in ``--cloud-frame`` at ``--rate`` (``--bad-stamp``: with a nanosec of 1.5e9, which
the node refuses as ``bad_stamp`` before anything else). It prints ``ready`` once its entities exist, runs
until stdin closes (or ``--seconds`` pass), then prints one JSON line: the closures read (query id, match
id, query robot, match robot), the number of diagnostics messages read and the newest value of every
diagnostics key, the clouds sent, and the matched remote writers and readers.

DDS stays on loopback: the domain comes from ``--domain`` and the configuration is
``cyclonedds_loopback.xml`` (interface lo, no multicast, peer 127.0.0.1) with the security section added.
That section has the authentication include the handshake's optional fields, which rustdds requires
(third_party/README.md).
"""

import argparse
import dataclasses
import glob
import json
import os
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from cyclonedds.core import Listener, Policy, Qos
from cyclonedds.domain import Domain, DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import sequence, uint8, uint32
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from dcloc_testlib import (CYCLONEDDS_CONFIG, Header, LoopClosure, apply_loopback_env,
                           cyclone_qos_loop_closure, dds_topic_name)

# Where Debian's libddsc0debian package puts the plugins (not on the loader's search path).
PLUGIN_GLOB = "/usr/lib/*/libddsc0debian/libdds_security_auth.so"


@dataclass
class PointField(IdlStruct, typename="sensor_msgs::msg::dds_::PointField_"):
    """sensor_msgs/msg/PointField."""

    name: str = ""
    offset: uint32 = 0
    datatype: uint8 = 0
    count: uint32 = 0


@dataclass
class PointCloud2(IdlStruct, typename="sensor_msgs::msg::dds_::PointCloud2_"):
    """sensor_msgs/msg/PointCloud2."""

    header: Header = dataclasses.field(default_factory=Header)
    height: uint32 = 0
    width: uint32 = 0
    fields: sequence[PointField] = dataclasses.field(default_factory=list)
    is_bigendian: bool = False
    point_step: uint32 = 0
    row_step: uint32 = 0
    data: sequence[uint8] = dataclasses.field(default_factory=list)
    is_dense: bool = False


@dataclass
class KeyValue(IdlStruct, typename="diagnostic_msgs::msg::dds_::KeyValue_"):
    """diagnostic_msgs/msg/KeyValue."""

    key: str = ""
    value: str = ""


@dataclass
class DiagnosticStatus(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticStatus_"):
    """diagnostic_msgs/msg/DiagnosticStatus."""

    level: uint8 = 0  # ROS byte: an octet on the wire
    name: str = ""
    message: str = ""
    hardware_id: str = ""
    values: sequence[KeyValue] = dataclasses.field(default_factory=list)


@dataclass
class DiagnosticArray(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticArray_"):
    """diagnostic_msgs/msg/DiagnosticArray."""

    header: Header = dataclasses.field(default_factory=Header)
    status: sequence[DiagnosticStatus] = dataclasses.field(default_factory=list)


def plugin_dir() -> Path:
    """The directory of the DDS Security plugins: $DCLOC_CYCLONE_PLUGINS, else Debian's."""
    if os.environ.get("DCLOC_CYCLONE_PLUGINS"):
        return Path(os.environ["DCLOC_CYCLONE_PLUGINS"])
    found = sorted(glob.glob(PLUGIN_GLOB))
    if not found:
        raise SystemExit(f"no DDS Security plugins at {PLUGIN_GLOB} (apt-get install libddsc0debian)")
    return Path(found[0]).parent


def security_xml(enclave: Path) -> str:
    """The <Security> element of a Cyclone configuration for an sros2 enclave directory."""
    plugins = plugin_dir()

    def library(kind: str, function: str) -> str:
        return (f'<Library path="{plugins / f"libdds_security_{kind}.so"}" '
                f'initFunction="init_{function}" finalizeFunction="finalize_{function}"/>')

    def file(name: str) -> str:
        path = enclave / name
        if not path.is_file():
            raise SystemExit(f"enclave {enclave} has no {name}")
        return f"file:{path.resolve()}"

    return f"""<Security>
      <Authentication>
        {library("auth", "authentication")}
        <IdentityCA>{file("identity_ca.cert.pem")}</IdentityCA>
        <IdentityCertificate>{file("cert.pem")}</IdentityCertificate>
        <PrivateKey>{file("key.pem")}</PrivateKey>
        <IncludeOptionalFields>true</IncludeOptionalFields>
      </Authentication>
      <AccessControl>
        {library("ac", "access_control")}
        <PermissionsCA>{file("permissions_ca.cert.pem")}</PermissionsCA>
        <Governance>{file("governance.p7s")}</Governance>
        <Permissions>{file("permissions.p7s")}</Permissions>
      </AccessControl>
      <Cryptographic>
        {library("crypto", "crypto")}
      </Cryptographic>
    </Security>"""


def config(enclave: Path | None) -> str:
    """The loopback configuration, with the security section when an enclave is given."""
    xml = CYCLONEDDS_CONFIG.read_text()
    if enclave is None:
        return xml
    return xml.replace("</Domain>", security_xml(enclave) + "\n  </Domain>", 1)


def stdin_closed() -> threading.Event:
    """An event set once stdin closes (the test's request to finish)."""
    event = threading.Event()

    def drain() -> None:
        for _ in sys.stdin:
            pass
        event.set()

    threading.Thread(target=drain, daemon=True).start()
    return event


def empty_cloud(frame: str, bad_stamp: bool) -> PointCloud2:
    """An empty cloud in ``frame`` stamped now (nanosec 1.5e9 with ``bad_stamp``)."""
    now = time.time()
    cloud = PointCloud2()
    cloud.header.frame_id = frame
    cloud.header.stamp.sec = int(now)
    cloud.header.stamp.nanosec = 1_500_000_000 if bad_stamp else int((now % 1) * 1e9)
    return cloud


def diagnostics_values(message: DiagnosticArray, into: dict) -> None:
    """Puts every key of ``message`` into ``into`` (newer values replace older ones)."""
    for status in message.status:
        for kv in status.values:
            into[kv.key] = kv.value


class Matches:
    """Matched remote endpoints of one reader or writer, from its listener (the 0.10 binding has no
    getter for the matched status)."""

    def __init__(self) -> None:
        self.current = 0
        self.listener = Listener(on_subscription_matched=self._seen, on_publication_matched=self._seen)

    def _seen(self, _entity: object, status: object) -> None:
        self.current = status.current_count


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--domain", type=int, required=True)
    p.add_argument("--enclave", type=Path, help="sros2 enclave directory; unsecured without")
    p.add_argument("--closures", default="/dc_loc/loop_closures")
    p.add_argument("--cloud-topic", help="publish empty clouds on this topic")
    p.add_argument("--cloud-frame", default="cyclone")
    p.add_argument("--bad-stamp", action="store_true")
    p.add_argument("--rate", type=float, default=10.0)
    p.add_argument("--seconds", type=float, help="stop after this long (default: when stdin closes)")
    args = p.parse_args()

    apply_loopback_env(args.domain)
    domain = Domain(args.domain, config(args.enclave))
    participant = DomainParticipant(args.domain)
    closure_writers, cloud_readers = Matches(), Matches()
    closures = DataReader(participant,
                          Topic(participant, dds_topic_name(args.closures), LoopClosure),
                          qos=cyclone_qos_loop_closure(depth=10000), listener=closure_writers.listener)
    diagnostics = DataReader(participant,
                             Topic(participant, dds_topic_name("/diagnostics"), DiagnosticArray),
                             qos=Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(100)))
    clouds = None
    if args.cloud_topic:
        clouds = DataWriter(participant,
                            Topic(participant, dds_topic_name(args.cloud_topic), PointCloud2),
                            qos=Qos(Policy.Reliability.Reliable(max_blocking_time=duration(seconds=1)),
                                    Policy.History.KeepLast(10)),
                            listener=cloud_readers.listener)
    print("ready", flush=True)

    stop = stdin_closed() if args.seconds is None else threading.Event()
    deadline = None if args.seconds is None else time.monotonic() + args.seconds
    got_closures: list[list[int]] = []
    diag_count = 0
    diag_last: dict[str, str] = {}
    sent = 0
    while not stop.is_set() and (deadline is None or time.monotonic() < deadline):
        if clouds is not None:
            clouds.write(empty_cloud(args.cloud_frame, args.bad_stamp))
            sent += 1
        for c in closures.take(N=1000):
            got_closures.append([c.query_id, c.match_id, c.query_robot, c.match_robot])
        for d in diagnostics.take(N=100):
            diag_count += 1
            diagnostics_values(d, diag_last)
        time.sleep(1.0 / args.rate)
    for c in closures.take(N=10000):
        got_closures.append([c.query_id, c.match_id, c.query_robot, c.match_robot])

    report = {
        "secured": args.enclave is not None,
        "closures": got_closures,
        "diagnostics": diag_count,
        "diagnostics_values": diag_last,
        "clouds_sent": sent,
        "closure_writers_matched": closure_writers.current,
        "cloud_readers_matched": cloud_readers.current,
    }
    print(json.dumps(report), flush=True)
    del domain
    return 0


if __name__ == "__main__":
    sys.exit(main())

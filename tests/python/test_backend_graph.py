"""Optimises the pose graph of examples/backend_gtsam.py offline for several variants of the same closures.
Run by tests/backend.rs with the venv's interpreter (no DDS here):

    test_backend_graph.py --bag DIR --variants VARIANTS.json --out RESULT.json

VARIANTS.json: ``{"name": {"closures": [ClosureRecord JSON objects], "rotate_covariance": DEG}, ...}``.
The odometry path lengths for the noise model come from the bag's ``/odom`` (what the live back end
received). RESULT.json: ``{"name": [[key, stamp, x, y, yaw], ...]}``, oldest keyframe first.
"""

import argparse
import importlib.util
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import dcloc_testlib as tl


def load_backend():
    """examples/backend_gtsam.py as a module."""
    spec = importlib.util.spec_from_file_location("backend_gtsam", tl.REPO / "examples" / "backend_gtsam.py")
    module = importlib.util.module_from_spec(spec)
    # dataclasses look their module up in sys.modules.
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def odometry_path(backend, bag: Path):
    """The bag's /odom as the back end's PathLength."""
    from nav_msgs.msg import Odometry
    from rclpy.serialization import deserialize_message
    from rosbags.rosbag2 import Reader

    path = backend.PathLength()
    with Reader(bag) as reader:
        conns = [c for c in reader.connections if c.topic == "/odom"]
        for _, _, raw in reader.messages(connections=conns):
            m = deserialize_message(bytes(raw), Odometry)
            s = m.header.stamp
            path.add(s.sec + s.nanosec * 1e-9, m.pose.pose.position.x, m.pose.pose.position.y)
    return path


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--bag", required=True, type=Path)
    ap.add_argument("--variants", required=True, type=Path)
    ap.add_argument("--out", required=True, type=Path)
    a = ap.parse_args()
    backend = load_backend()
    path = odometry_path(backend, a.bag)
    out = {}
    for name, v in json.loads(a.variants.read_text()).items():
        closures = [backend.Closure.from_record(r) for r in v["closures"]]
        rows = backend.optimise(closures, path, rotate_covariance_deg=v.get("rotate_covariance", 0.0))
        out[name] = [list(r) for r in rows]
    a.out.write_text(json.dumps(out))
    print(f"graph variants: {', '.join(f'{k} ({len(r)} keyframes)' for k, r in out.items())}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

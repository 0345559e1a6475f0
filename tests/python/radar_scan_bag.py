"""Copies a rosbag2 bag, turning every sensor_msgs/PointCloud2 (fields x, y, z, v_r) into the
radar_msgs/RadarScan of the same detections (range, azimuth, elevation, doppler_velocity = v_r, amplitude 0)
on the same topic with the same header; every other message is copied unchanged. Written with the rosbags
library alone (radar_msgs registered from tests/python/interfaces/radar_msgs/msg), so the bag is what a
recorder of a radar_msgs driver writes, not what dc_loc writes. Run by tests/cli.rs with the venv's
interpreter:

    radar_scan_bag.py IN_BAG OUT_BAG
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import numpy as np
from rosbags.rosbag2 import Reader, Writer
from rosbags.rosbag2.enums import StoragePlugin
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

INTERFACES = Path(__file__).resolve().parent / "interfaces" / "radar_msgs" / "msg"
CLOUD = "sensor_msgs/msg/PointCloud2"
SCAN = "radar_msgs/msg/RadarScan"


def typestore():
    """ROS 2 Jazzy types plus radar_msgs from its .msg files."""
    store = get_typestore(Stores.ROS2_JAZZY)
    for name in ("RadarReturn", "RadarScan"):
        text = (INTERFACES / f"{name}.msg").read_text()
        store.register(get_types_from_msg(text, f"radar_msgs/msg/{name}"))
    return store


def as_scan(store, cloud):
    """The RadarScan of a PointCloud2's detections."""
    kinds = {7: "f4", 8: "f8"}
    order = ">" if cloud.is_bigendian else "<"
    dtype = np.dtype({"names": [f.name for f in cloud.fields],
                      "formats": [order + kinds[f.datatype] for f in cloud.fields],
                      "offsets": [f.offset for f in cloud.fields], "itemsize": cloud.point_step})
    pts = np.frombuffer(cloud.data.tobytes(), dtype=dtype, count=cloud.width * cloud.height)
    x, y, z = (pts[k].astype(float) for k in ("x", "y", "z"))
    r = np.sqrt(x * x + y * y + z * z)
    el = np.where(r > 0, np.arcsin(np.divide(z, r, out=np.zeros_like(r), where=r > 0)), 0.0)
    az = np.arctan2(y, x)
    ret = store.types["radar_msgs/msg/RadarReturn"]
    returns = [ret(range=float(r[i]), azimuth=float(az[i]), elevation=float(el[i]),
                   doppler_velocity=float(pts["v_r"][i]), amplitude=0.0) for i in range(len(pts))]
    return store.types[SCAN](header=cloud.header, returns=returns)


def main() -> int:
    src, dst = Path(sys.argv[1]), Path(sys.argv[2])
    store = typestore()
    if dst.exists():
        shutil.rmtree(dst)
    scans = 0
    with Reader(src) as reader, Writer(dst, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conns = {}
        for c in reader.connections:
            msgtype = SCAN if c.msgtype == CLOUD else c.msgtype
            conns[c.id] = writer.add_connection(c.topic, msgtype, typestore=store,
                                                offered_qos_profiles=c.ext.offered_qos_profiles)
        for c, t, raw in reader.messages():
            if c.msgtype == CLOUD:
                msg = as_scan(store, store.deserialize_cdr(raw, CLOUD))
                raw = store.serialize_cdr(msg, SCAN)
                scans += 1
            writer.write(conns[c.id], t, raw)
    print(f"{scans} clouds written as {SCAN} to {dst}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

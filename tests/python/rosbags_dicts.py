"""Plain-dict <-> rosbags message conversion shared by the bag test scripts.

A message dict uses the .msg field names, nested dicts for nested messages, lists of ints for
uint8[] and lists of floats for float64[36]: the same JSON that serde_json makes of the Rust structs in
crates/core/src/msgs.rs, so one JSON value describes a message on both sides.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.base import Nodetype

REPO = Path(__file__).resolve().parents[2]

# dc_loc/msg/LoopClosure: read from the interface package when the repository has it (msg/), else this
# copy of the same text, so the Python side never takes the definition from the Rust code under test.
LOOP_CLOSURE_TYPE = 'dc_loc/msg/LoopClosure'
LOOP_CLOSURE_MSG = """\
std_msgs/Header header                 # stamp: query keyframe time; frame_id: body frame
uint64 query_id                        # newer keyframe
uint64 match_id                        # older, revisited keyframe (its id in match_robot's map)
int32 query_robot                      # node.robot_id of the node that published the closure
int32 match_robot                      # robot of the match keyframe (query_robot unless another robot's)
builtin_interfaces/Time query_stamp
builtin_interfaces/Time match_stamp
geometry_msgs/Pose query_odom_pose     # odometry poses of the two keyframes
geometry_msgs/Pose match_odom_pose
geometry_msgs/PoseWithCovariance relative_pose   # query body frame in the match body frame; covariance row-major x y z rotx roty rotz
uint32 inliers
float64 score
"""


def loop_closure_msg_text() -> str:
    """LoopClosure.msg as the repository's interface package has it (or the copy above)."""
    path = REPO / 'msg' / 'LoopClosure.msg'
    return path.read_text() if path.exists() else LOOP_CLOSURE_MSG


def typestore():
    """The ROS 2 Jazzy typestore with dc_loc/msg/LoopClosure registered."""
    store = get_typestore(Stores.ROS2_JAZZY)
    store.register(get_types_from_msg(loop_closure_msg_text(), LOOP_CLOSURE_TYPE))
    return store


def _value_from(store, desc, value):
    kind, sub = desc
    if kind == Nodetype.BASE:
        return value
    if kind == Nodetype.NAME:
        return msg_from_dict(store, sub, value)
    (elem_kind, elem), _bound = sub
    if elem_kind == Nodetype.BASE:
        return np.array(value, dtype=np.dtype(elem[0]) if elem[0] != 'bool' else np.bool_)
    return [_value_from(store, (elem_kind, elem), v) for v in value]


def msg_from_dict(store, typename: str, d: dict):
    """Builds a rosbags message of `typename` from its dict."""
    _, fields = store.fielddefs[typename]
    cls = store.types[typename]
    missing = {name for name, _ in fields} ^ set(d)
    if missing:
        raise KeyError(f'{typename}: fields differ from the dict: {sorted(missing)}')
    return cls(**{name: _value_from(store, desc, d[name]) for name, desc in fields})


def _value_to(store, desc, value):
    kind, sub = desc
    if kind == Nodetype.BASE:
        return value.item() if isinstance(value, np.generic) else value
    if kind == Nodetype.NAME:
        return msg_to_dict(store, sub, value)
    (elem_kind, elem), _bound = sub
    if elem_kind == Nodetype.BASE:
        return [v.item() if isinstance(v, np.generic) else v for v in value]
    return [_value_to(store, (elem_kind, elem), v) for v in value]


def msg_to_dict(store, typename: str, msg) -> dict:
    """The dict of a rosbags message of `typename`."""
    _, fields = store.fielddefs[typename]
    return {name: _value_to(store, desc, getattr(msg, name)) for name, desc in fields}

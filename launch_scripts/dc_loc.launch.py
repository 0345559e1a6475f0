"""Launches the dc_loc node (ros2 launch dc_loc.launch.py params_file:=... namespace:=... odom_topic:=...).

Arguments
- params_file: ROS 2 params YAML (default: params/dc_loc.yaml next to this directory).
- namespace: node namespace (default empty).
- node_name: node name (default dc_loc; the params file section must use it, or `/**`).
- odom_topic: nav_msgs/Odometry topic remapped onto the configured `odometry.topic` `/odom`.
- log_level: debug, info, warn or error (default info).
- dc_loc: the dc_loc executable (default: the installed node of the colcon package, lib/dc_loc/dc_loc,
  when this file is the installed share/dc_loc/launch/dc_loc.launch.py; else the repository's
  target/release/dc_loc; else `dc_loc` on PATH).
Parameters go to the node as `--ros-args --params-file`, the log level as `--ros-args --log-level`
(launch_ros puts both after the node's own `--ros-args`). The node reads ROS_DOMAIN_ID and ROS_AUTOMATIC_DISCOVERY_RANGE from the environment, as every ROS 2 node.
"""

import os

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

HERE = os.path.dirname(os.path.abspath(__file__))


def default_executable() -> str:
    """The installed node (prefix/share/dc_loc/launch -> prefix/lib/dc_loc), the repository's build, or
    `dc_loc` on PATH."""
    for candidate in (os.path.join(HERE, "..", "..", "..", "lib", "dc_loc", "dc_loc"),
                      os.path.join(HERE, "..", "target", "release", "dc_loc")):
        if os.access(candidate, os.X_OK):
            return os.path.normpath(candidate)
    return "dc_loc"


def generate_launch_description():
    args = [
        DeclareLaunchArgument("params_file",
                              default_value=os.path.join(HERE, "..", "params", "dc_loc.yaml")),
        DeclareLaunchArgument("namespace", default_value=""),
        DeclareLaunchArgument("node_name", default_value="dc_loc"),
        DeclareLaunchArgument("odom_topic", default_value="/odom"),
        DeclareLaunchArgument("log_level", default_value="info"),
        DeclareLaunchArgument("dc_loc", default_value=default_executable()),
    ]
    node = Node(
        executable=LaunchConfiguration("dc_loc"),
        name=LaunchConfiguration("node_name"),
        namespace=LaunchConfiguration("namespace"),
        parameters=[LaunchConfiguration("params_file")],
        remappings=[("/odom", LaunchConfiguration("odom_topic"))],
        ros_arguments=["--log-level", LaunchConfiguration("log_level")],
        output="screen",
        emulate_tty=True,
    )
    return LaunchDescription(args + [node])

#!/usr/bin/env bash
# Starts the dc_loc ROS 2 node without ros2 launch.
#
#   launch_scripts/dc_loc.sh [-p PARAMS_FILE] [-n NAMESPACE] [-o ODOM_TOPIC] [-l LOG_LEVEL] [-- EXTRA ROS ARGS]
#
# Defaults: params/dc_loc.yaml, no namespace, odometry on /odom, log level info; the binary is $DC_LOC, else
# target/release/dc_loc of this checkout, else dc_loc on PATH. ROS_DOMAIN_ID and ROS_AUTOMATIC_DISCOVERY_RANGE
# are passed through (LOCALHOST keeps every packet on loopback). SIGINT/SIGTERM reach the node (exec): it
# publishes its last closures and saves the map before it exits.
set -euo pipefail
here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
repo=$(cd "$here/.." && pwd)
params=$repo/params/dc_loc.yaml
namespace=""
odom=/odom
level=info
while getopts "p:n:o:l:h" opt; do
    case $opt in
        p) params=$OPTARG ;;
        n) namespace=$OPTARG ;;
        o) odom=$OPTARG ;;
        l) level=$OPTARG ;;
        h) sed -n '2,10p' "${BASH_SOURCE[0]}"; exit 0 ;;
        *) exit 2 ;;
    esac
done
shift $((OPTIND - 1))
[ "${1:-}" = "--" ] && shift
bin=${DC_LOC:-}
if [ -z "$bin" ]; then
    if [ -x "$repo/target/release/dc_loc" ]; then bin=$repo/target/release/dc_loc; else bin=dc_loc; fi
fi
args=(--ros-args --params-file "$params" --log-level "$level")
[ -n "$namespace" ] && args+=(-r "__ns:=$namespace")
[ "$odom" != /odom ] && args+=(-r "/odom:=$odom")
exec "$bin" "${args[@]}" "$@"

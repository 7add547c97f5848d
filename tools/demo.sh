#!/usr/bin/env bash
# Set up, then run the installed skin_node on the humanoid while mocap_player
# plays the built-in clip; the node prints its figures (frames/s, ms per frame
# and per stage, receive->publish latency) once a second. Stops after
# DEMO_SECONDS (default 20) of playback.
set -euo pipefail
cd "$(dirname "$0")/.."
bash tools/setup.sh
. tools/env.sh
export ROS_DOMAIN_ID=${ROS_DOMAIN_ID:-37}
seconds=${DEMO_SECONDS:-20}
log=$(mktemp)

skin_node --ros-args --params-file ws/install/skin_node/share/skin_node/config/humanoid.yaml \
  > >(tee "$log") 2>&1 &
node=$!
cleanup() { kill -TERM "$node" "${player:-}" 2>/dev/null || true; wait 2>/dev/null || true; rm -f "$log"; }
trap cleanup EXIT

echo "demo: waiting for skin_node set-up (the first run builds and caches the rig)"
until grep -q ": ready in" "$log"; do
  kill -0 "$node" 2>/dev/null || { echo "demo: skin_node failed to start" >&2; exit 1; }
  sleep 0.5
done

mocap_player --character humanoid --loop &
player=$!
sleep "$seconds"
echo "demo: stopping after ${seconds} s"

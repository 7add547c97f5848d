#!/usr/bin/env bash
# Create .venv (Python deps, rclpy and message packages from wheels: no ROS
# install needed) and build skin_node with colcon into ./ws.
# Re-running is cheap: pip runs only when the dependency list changed.
set -euo pipefail
cd "$(dirname "$0")/.."

DEPS=(
  numpy numba scipy trimesh pyyaml scikit-image psutil matplotlib pygltflib usd-core
  ros-jazzy-rclpy ros-jazzy-common-interfaces ros-jazzy-rmw-fastrtps-cpp
  rosbags colcon-common-extensions pytest
)
PYTHON=${PYTHON:-python3}

if [ ! -x .venv/bin/python ]; then
  echo "setup: creating .venv with $($PYTHON --version)"
  if ! "$PYTHON" -m venv .venv 2>/dev/null; then
    # Debian and Ubuntu ship venv apart from python3: install it when we may.
    rm -rf .venv
    pyver=$("$PYTHON" -c 'import sys; print(f"{sys.version_info[0]}.{sys.version_info[1]}")')
    if command -v apt-get >/dev/null && [ "$(id -u)" = 0 ]; then
      apt-get update -qq && apt-get install -y -qq "python${pyver}-venv" python3-venv >/dev/null
    elif command -v apt-get >/dev/null && command -v sudo >/dev/null; then
      sudo apt-get update -qq && sudo apt-get install -y -qq "python${pyver}-venv" python3-venv >/dev/null
    else
      echo "setup: '$PYTHON -m venv' failed; install your distribution's python venv package" >&2
      exit 1
    fi
    "$PYTHON" -m venv .venv
  fi
fi
# tools/constraints.txt pins every version (see its header).
stamp=.venv/.skin_node_deps
want="${DEPS[*]} $(cksum < tools/constraints.txt)"
if [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
  echo "setup: installing ${DEPS[*]} (versions from tools/constraints.txt)"
  .venv/bin/python -m pip install --quiet --upgrade pip
  .venv/bin/python -m pip install --quiet -c tools/constraints.txt "${DEPS[@]}"
  echo "$want" > "$stamp"
fi

# --paths (not --base-paths): colcon must not crawl into .venv, whose wheels
# carry package.xml files of their own.
echo "setup: colcon build into ws/"
mkdir -p ws
.venv/bin/colcon --log-base ws/log build --paths . \
  --build-base ws/build --install-base ws/install --event-handlers console_cohesion- \
  > ws/colcon.out 2>&1 || { cat ws/colcon.out; exit 1; }
echo "setup: installed ws/install/skin_node/lib/skin_node/{skin_node,mocap_player,skin_bag,skin_bench}"

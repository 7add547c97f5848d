# Source me: puts the colcon install of skin_node and .venv on the path.
# Sourcing ws/install/setup.bash would need ROS' own setup scripts; the
# wheels need only PATH and PYTHONPATH.
_top=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
_site=$(echo "$_top"/ws/install/skin_node/lib/python3*/site-packages)
export PATH="$_top/ws/install/skin_node/lib/skin_node:$_top/.venv/bin:$PATH"
export PYTHONPATH="$_site${PYTHONPATH:+:$PYTHONPATH}"
export AMENT_PREFIX_PATH="$_top/ws/install/skin_node${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"
# DDS stays on this machine.
export ROS_AUTOMATIC_DISCOVERY_RANGE=${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}
unset _top _site

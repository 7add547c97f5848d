#!/usr/bin/env bash
# Set up (.venv, colcon build into ws/) and run the whole test suite.
set -uo pipefail
cd "$(dirname "$0")/.."
bash tools/setup.sh || exit 1
. tools/env.sh
export ROS_DOMAIN_ID=${ROS_DOMAIN_ID:-42}
python -m pytest -q -p no:cacheprovider test "$@"
rc=$?
# pytest exits 5 when it collected no test: that is a broken suite, not a pass.
[ "$rc" -eq 5 ] && echo "test.sh: no tests were collected" >&2
exit "$rc"

"""colcon installs skin_node where ROS 2 tools look for an ament_python package."""
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from skin_node.ros_domain import claim_domain

REPO = Path(__file__).resolve().parents[1]


def test_colcon_install_layout(tmp_path):
    colcon = shutil.which("colcon") or str(Path(sys.executable).with_name("colcon"))
    if not Path(colcon).exists():
        pytest.skip("colcon is not installed")
    # --paths, not --base-paths: the crawl must not wander into a venv in the repo.
    res = subprocess.run(
        [colcon, "--log-base", str(tmp_path / "log"), "build", "--paths", str(REPO),
         "--build-base", str(tmp_path / "build"), "--install-base", str(tmp_path / "install")],
        cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stdout + res.stderr
    prefix = tmp_path / "install" / "skin_node"
    for script in ("skin_node", "mocap_player", "skin_bag", "skin_bench"):
        exe = prefix / "lib" / "skin_node" / script
        assert exe.is_file() and os.access(exe, os.X_OK), exe
    index = prefix / "share" / "ament_index" / "resource_index" / "packages"
    assert (index / "skin_node").is_file()
    assert (prefix / "share" / "skin_node" / "package.xml").is_file()
    for name in ("arm.yaml", "humanoid.yaml", "name_map_example.yaml"):
        assert (prefix / "share" / "skin_node" / "config" / name).is_file()
    site = next(prefix.glob("lib/python3*/site-packages"))
    for package in ("skin_node", "msg_adapters"):
        assert (site / package / "__init__.py").is_file()

    # The installed node starts from the install tree alone (not the source tree).
    with claim_domain() as claim:
        env = dict(os.environ, PYTHONPATH=str(site), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
                   ROS_DOMAIN_ID=str(claim.domain))
        res = subprocess.run([str(prefix / "lib" / "skin_node" / "skin_node"),
                              "--ros-args", "-p", "character:=no_such_character"],
                             cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)
    assert res.returncode == 2
    assert res.stderr.startswith("skin_node: error: no_such_character")

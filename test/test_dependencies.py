"""Every package the code imports is declared where users look: setup.py, package.xml, the
README's install lines and tools/setup.sh."""
import ast
import re
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# import name -> distribution name, where the two differ
DIST_OF_IMPORT = {"yaml": "pyyaml", "skimage": "scikit-image", "pxr": "usd-core"}
# rosdep key -> the pip distribution it installs
DIST_OF_ROSDEP_KEY = {
    "python3-numpy": "numpy", "python3-scipy": "scipy", "python3-yaml": "pyyaml",
    "python3-numba": "numba", "python3-trimesh-pip": "trimesh",
    "python3-skimage": "scikit-image", "python3-rosbags-pip": "rosbags",
    "python3-psutil": "psutil", "python3-matplotlib": "matplotlib", "python3-usd": "usd-core",
}
# ROS packages: they come with the ROS installation (or its wheels), not from setup.py
ROS_PACKAGES = {"rclpy", "ament_index_python", "rcl_interfaces", "builtin_interfaces",
                "std_msgs", "geometry_msgs", "sensor_msgs", "shape_msgs",
                "visualization_msgs", "diagnostic_msgs"}
OWN = {"skin_node", "msg_adapters"}


def _imported_top_names() -> set:
    names = set()
    for path in list((ROOT / "skin_node").rglob("*.py")) + list((ROOT / "msg_adapters").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                names.update(a.name.split(".")[0] for a in node.names)
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names.add(node.module.split(".")[0])
    return names - OWN - set(sys.stdlib_module_names)


def _install_requires() -> set:
    tree = ast.parse((ROOT / "setup.py").read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.keyword) and node.arg == "install_requires":
            return {ast.literal_eval(e) for e in node.value.elts} - {"setuptools"}
    raise AssertionError("setup.py has no install_requires")


def _package_xml_depends() -> set:
    root = ET.parse(ROOT / "package.xml").getroot()
    return {e.text.strip() for e in root if e.tag in ("exec_depend", "depend")}


def _readme_pip_lines() -> list:
    return [set(m.group(1).split()) for m in
            re.finditer(r"pip install ([a-z0-9 _-]+)", (ROOT / "README.md").read_text())]


def test_every_imported_package_is_installed_by_setup_py_or_ros():
    requires = _install_requires()
    missing = {n for n in _imported_top_names() - ROS_PACKAGES
               if DIST_OF_IMPORT.get(n, n) not in requires}
    assert not missing, f"imported but not in setup.py's install_requires: {sorted(missing)}"


def test_package_xml_declares_every_runtime_dependency():
    depends = _package_xml_depends()
    unknown = {k for k in depends if k.startswith("python3-") and k not in DIST_OF_ROSDEP_KEY}
    assert not unknown, f"package.xml keys this test cannot map to a distribution: {unknown}"
    missing_ros = (_imported_top_names() & ROS_PACKAGES) - depends
    assert not missing_ros, f"ROS packages imported but not in package.xml: {missing_ros}"
    by_rosdep = {DIST_OF_ROSDEP_KEY[k] for k in depends if k in DIST_OF_ROSDEP_KEY}
    # what rosdep cannot install, the README's line after `rosdep install` must
    pip_lines = _readme_pip_lines()
    assert pip_lines, "README has no pip install line"
    after_rosdep = min(pip_lines, key=len)
    missing = _install_requires() - by_rosdep - after_rosdep
    assert not missing, f"neither package.xml nor the README's pip line installs {missing}"


def test_readme_full_pip_line_lists_exactly_setup_py():
    full = max(_readme_pip_lines(), key=len)
    assert full == _install_requires(), (
        f"README pip line differs from setup.py: missing {_install_requires() - full}, "
        f"extra {full - _install_requires()}")


def test_tools_setup_installs_everything_setup_py_needs():
    text = (ROOT / "tools" / "setup.sh").read_text()
    deps = set(re.search(r"DEPS=\(([^)]*)\)", text).group(1).split())
    missing = _install_requires() - deps
    assert not missing, f"tools/setup.sh does not install {missing}"
    assert {"ros-jazzy-rclpy", "ros-jazzy-common-interfaces"} <= deps

"""ament_python packaging: the core, the ROS shell and its message adapters."""
from glob import glob

from setuptools import find_packages, setup

PACKAGE = "skin_node"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", sorted(glob("config/*.yaml"))),
        (f"share/{PACKAGE}/config/templates", sorted(glob("config/templates/*.yaml"))),
    ],
    # rclpy and the message packages come from the ROS installation (or its wheels).
    install_requires=["setuptools", "numpy", "numba", "trimesh", "scipy", "pyyaml",
                      "scikit-image", "rosbags", "psutil", "matplotlib", "pygltflib",
                      "usd-core"],
    zip_safe=True,
    maintainer="skin_node maintainers",
    maintainer_email="maintainers@skin-node.invalid",
    description="Skin deformation from joint states, as a ROS 2 node.",
    license="BSD-3-Clause",
    tests_require=["pytest"],
    entry_points={
        "console_scripts": [
            "skin_node = skin_node.node:main",
            "mocap_player = skin_node.player:main",
            "skin_bag = skin_node.bag_tool:main",
            "skin_bench = skin_node.bench.cli:main",
        ],
    },
)

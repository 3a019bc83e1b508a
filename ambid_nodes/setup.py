import os
import sys
from glob import glob

from setuptools import Extension, find_packages, setup

package_name = "ambid_nodes"

# one console entry point per node: <executable> = ambid_nodes.<module>:main
NODES = ["plant_sim", "position_controller", "excitation_generator", "recorder", "hardware_bridge", "frf_consumer",
         "live_view"]


def ros_prefixes() -> list[str]:
    """Where ROS 2's headers and libraries are: this interpreter's prefix (ROS 2 from PyPI
    wheels) and the sourced workspaces (AMENT_PREFIX_PATH); those holding rcl."""
    roots = [sys.prefix, *os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep)]
    found = [r for r in dict.fromkeys(roots) if r and os.path.isfile(os.path.join(r, "include", "rcl", "rcl", "rcl.h"))]
    if not found:
        raise SystemExit("ambid_nodes: rcl's headers (include/rcl/rcl/rcl.h) are in neither this Python's prefix "
                         f"{sys.prefix} nor AMENT_PREFIX_PATH; run './launch_scripts/ambid setup'")
    return found


ROS = ros_prefixes()
# Jazzy installs each package's headers under include/<package>/
ROS_INCLUDES = sorted(d for r in ROS for d in glob(os.path.join(r, "include", "*")) if os.path.isdir(d))

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(include=["ambid_nodes", "ambid_nodes.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/config", glob("config/*.yaml")),
    ],
    # the loop nodes' per-sample kernel call and their message pump (see the C
    # files): they need a C compiler and Python's headers, the pump also rcl's headers and libraries
    ext_modules=[
        Extension("ambid_nodes._loop_call", ["ambid_nodes/_loop_call.c"], extra_compile_args=["-O2"]),
        Extension("ambid_nodes._loop_pump", ["ambid_nodes/_loop_pump.c"], extra_compile_args=["-O2"],
                  include_dirs=ROS_INCLUDES, libraries=["rcl", "rmw", "rcutils"],
                  library_dirs=[os.path.join(r, "lib") for r in ROS]),
    ],
    # the numerical core is its own distribution (../ambid_core, pip install ./ambid_core)
    install_requires=["setuptools", "ambid"],
    zip_safe=False,
    maintainer="ambid maintainers",
    maintainer_email="maintainers@ambid.dev",
    description="rclpy nodes of the ambid AMB identification toolkit",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [f"{n} = ambid_nodes.{n}:main" for n in NODES],
    },
)

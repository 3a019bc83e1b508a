from glob import glob

from setuptools import Extension, find_packages, setup

package_name = "ambid_nodes"

# one console entry point per node: <executable> = ambid_nodes.<module>:main
NODES = ["plant_sim", "position_controller", "excitation_generator", "recorder", "hardware_bridge", "frf_consumer"]

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(include=["ambid", "ambid.*", "ambid_nodes", "ambid_nodes.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/config", glob("config/*.yaml")),
    ],
    # the loop nodes' per-sample kernel call (see the C file); needs a C compiler and Python's headers
    ext_modules=[Extension("ambid_nodes._loop_call", ["ambid_nodes/_loop_call.c"], extra_compile_args=["-O2"])],
    install_requires=["setuptools"],
    zip_safe=False,
    maintainer="ambid maintainers",
    maintainer_email="maintainers@ambid.dev",
    description="rclpy nodes and numerical core of the ambid AMB identification toolkit",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [f"{n} = ambid_nodes.{n}:main" for n in NODES],
    },
)

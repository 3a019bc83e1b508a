from glob import glob

from setuptools import find_packages, setup

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
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="ambid maintainers",
    maintainer_email="maintainers@ambid.dev",
    description="rclpy nodes and numerical core of the ambid AMB identification toolkit",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [f"{n} = ambid_nodes.{n}:main" for n in NODES],
    },
)

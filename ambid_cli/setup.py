from setuptools import find_packages, setup

package_name = "ambid_cli"

setup(
    name=package_name,
    version="0.2.0",
    packages=find_packages(include=["ambid_cli", "ambid_cli.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
    ],
    # the numerical core is its own distribution (../ambid_core, pip install ./ambid_core)
    install_requires=["setuptools", "ambid"],
    zip_safe=False,
    maintainer="ambid maintainers",
    maintainer_email="maintainers@ambid.dev",
    description="the ambid command line: identify, graph, fit, design, import, validate, bench, ...",
    license="Apache-2.0",
    entry_points={"console_scripts": ["ambid = ambid_cli.cli:main"]},
)

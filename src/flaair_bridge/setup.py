from setuptools import find_packages, setup

PACKAGE = "flaair_bridge"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + PACKAGE]),
        ("share/" + PACKAGE, ["package.xml"]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="FLAAIR developers",
    maintainer_email="dev@flaair.dev",
    description="FLAAIR real-time target bridge: the UDP protocol, the bridge node and an emulated "
    "target around the plant model.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "bridge_node = flaair_bridge.bridge_node:main",
            "emulated_target = flaair_bridge.emulated_target:main",
        ]
    },
)

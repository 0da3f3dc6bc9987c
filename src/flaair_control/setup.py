from setuptools import find_packages, setup

PACKAGE = "flaair_control"

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
    description="FLAAIR control: per-wingbeat collision monitor and the delayed-stretch-activation "
    "(dSA) asynchronous controller.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "collision_monitor_node = flaair_control.collision_monitor_node:main",
            "health_node = flaair_control.health_node:main",
            "dsa_controller_node = flaair_control.dsa_controller_node:main",
            "stroke_controller_node = flaair_control.stroke_controller_node:main",
        ]
    },
)

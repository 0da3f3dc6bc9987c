from setuptools import find_packages, setup

PACKAGE = "flaair_sim"

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
    description="FLAAIR plant simulation: flapping-wing stroke/pitch dynamics, PVDF sensors, "
    "missing effects; plant and drive nodes.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "plant_node = flaair_sim.plant_node:main",
            "drive_node = flaair_sim.drive_node:main",
        ]
    },
)

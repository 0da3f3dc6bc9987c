from setuptools import find_packages, setup

PACKAGE = "flaair_sensors"

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
    description="FLAAIR sensor front end: PVDF charge model, voltage-to-angle estimation, "
    "calibration and characterization.",
    license="Apache-2.0",
    entry_points={"console_scripts": ["frontend_node = flaair_sensors.frontend_node:main"]},
)

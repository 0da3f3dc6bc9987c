from setuptools import find_packages, setup

PACKAGE = "flaair_common"

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
    description="FLAAIR node plumbing: parameters from schemas, block message conversion, QoS, "
    "measured-run CSV I/O.",
    license="Apache-2.0",
    entry_points={"console_scripts": ["container = flaair_common.container:main"]},
)

from setuptools import find_packages, setup

PACKAGE = "flaair_analysis"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    package_data={"flaair_analysis.discrepancy": ["cases.yaml"]},
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + PACKAGE]),
        ("share/" + PACKAGE, ["package.xml"]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="FLAAIR developers",
    maintainer_email="dev@flaair.dev",
    description="FLAAIR science, pure (no ROS, no plots, no templates): the model-vs-measurement "
    "discrepancy workflow, grey-box identification, term discovery, per-wingbeat summaries and "
    "the closed-loop batch engine of the sweeps.",
    license="Apache-2.0",
    entry_points={"console_scripts": []},
)

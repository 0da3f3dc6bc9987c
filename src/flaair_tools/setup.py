from glob import glob

from setuptools import find_packages, setup

PACKAGE = "flaair_tools"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    package_data={PACKAGE: ["templates/*.j2"]},
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + PACKAGE]),
        ("share/" + PACKAGE, ["package.xml"]),
        # the graphs, as ROS 2 XML launch files (`flaair launch`, `ros2 launch flaair_tools ...`)
        ("share/" + PACKAGE + "/launch", sorted(glob("launch/*.launch.xml"))),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="FLAAIR developers",
    maintainer_email="dev@flaair.dev",
    description="FLAAIR tools: bag recorder/player/import, paper experiments, analysis report, "
    "the discrepancy and identify commands and reports (their science is flaair_analysis), the "
    "flaair command line.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "recorder_node = flaair_tools.recorder.recorder_node:main",
            "player = flaair_tools.recorder.player:main",
            "flaair = flaair_tools.cli:main",
            "foxglove_node = flaair_tools.liveview.foxglove_node:main",
        ]
    },
)

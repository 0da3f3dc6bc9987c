from glob import glob

from setuptools import find_packages, setup

PACKAGE = "flaair_model"
# The repository's config/ (every tunable number), installed to share/flaair_model/config where
# an installed FLAAIR finds it through the ament index (flaair_model.config.config_dir).
CONFIG_FILES = sorted(glob("../../config/*.yaml") + glob("../../config/*.json"))

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + PACKAGE]),
        ("share/" + PACKAGE, ["package.xml"]),
        ("share/" + PACKAGE + "/config", CONFIG_FILES),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="FLAAIR developers",
    maintainer_email="dev@flaair.dev",
    description="FLAAIR model: PVDF charge model, plant/sensor parameter dataclasses, effect "
    "registry, model files, config lookup.",
    license="Apache-2.0",
    entry_points={"console_scripts": []},
)

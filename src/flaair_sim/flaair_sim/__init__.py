"""FLAAIR plant simulation core: model parameters and effects (`model`), YAML I/O (`model_io`),
plant dynamics and sensor chain (`plant`), drive signals (`drive`).

Core modules import numpy, scipy and numba only; ROS nodes and the CLI sit on top of them.
"""

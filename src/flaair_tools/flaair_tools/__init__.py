"""FLAAIR tools, one subpackage per job.

- `bagio`: bags and data I/O (types, QoS, writer, reader and blocks, run markers, MCAP scan and
  recovery; runs from bags, measured-run CSV import);
- `recorder`: the recorder and the player;
- `roscli`: the ros2cli stand-ins (`bin/flaair topic|param|node|bag`);
- `analysis`: analysis of recorded runs and the report;
- `discrepancy`: the `discrepancy` and `identify` commands and their reports (the workflow itself
  is the pure `flaair_analysis.discrepancy`);
- `tables`: a lab's frequency-response tables (files, report, commands around the pure
  `flaair_analysis.tables`);
- `multisine`: odd random-phase multisines (`flaair multisine design|analyze`, the design file,
  the report around the pure `flaair_analysis.multisine`);
- `sweeps`: simulation studies on Dask;
- `liveview`: the Foxglove live view;
- `orchestration`: graphs brought up and run (experiments, `live`, the demo);
- `cli`: the `flaair` command, dispatching to each subcommand's module.

Arrows point down that list's layers (tests/test_layout_rules.py): `bagio` imports no other
subpackage, `orchestration` and `cli` sit on top.
"""

__all__ = [
    "analysis",
    "bagio",
    "cli",
    "discrepancy",
    "liveview",
    "multisine",
    "orchestration",
    "recorder",
    "roscli",
    "sweeps",
    "tables",
]

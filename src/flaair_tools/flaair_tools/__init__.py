"""FLAAIR tools: bag recorder/player/import, paper experiments, analysis report, model-vs-measurement discrepancy workflow, the flaair command line."""

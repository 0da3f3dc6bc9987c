"""FLAAIR node plumbing: parameters from schemas, config lookup, block message conversion, QoS, measured-run CSV I/O."""

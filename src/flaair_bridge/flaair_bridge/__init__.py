"""FLAAIR real-time target bridge: UDP protocol, bridge core and node, emulated target."""

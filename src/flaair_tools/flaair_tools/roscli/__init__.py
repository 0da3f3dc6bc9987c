"""Stand-ins for ros2cli, which PyPI does not carry: `bin/flaair topic|param|node|bag|service`.

Modules (import them by name; this package imports none of them eagerly):
- `topic`: list, echo, publish
- `param`: get and set a running node's parameters
- `node_cli`: list the running nodes
- `bag_cli`: bag info and recovery
- `service`: list services and call one
"""

__all__ = ["bag_cli", "node_cli", "param", "service", "topic"]

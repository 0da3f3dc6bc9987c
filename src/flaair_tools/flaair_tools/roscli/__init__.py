"""Stand-ins for ros2cli, which PyPI does not carry: `bin/flaair topic|param|node|bag|service`.

Modules (import them by name; this package imports none of them eagerly):
- `topic`: list, echo, hz, info, publish
- `param`: get and set a running node's parameters
- `node_cli`: list the running nodes
- `service`: list services, call one
- `bag_cli`: bag info and recovery
- `ros2_args`: ros2cli's discovery flags, hidden node names, one line for a flag not covered
- `yaml_out`: messages as YAML, as `ros2 topic echo` prints them
"""

__all__ = ["bag_cli", "node_cli", "param", "ros2_args", "service", "topic", "yaml_out"]

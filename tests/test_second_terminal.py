"""The export line `live`, `experiment` and `launch` print for a second terminal."""

from __future__ import annotations

import pytest

from flaair_common.graph import graph_env
from flaair_tools.orchestration.second_terminal import export_line, hint

pytestmark = pytest.mark.timeout(30)


def test_the_line_carries_exactly_what_the_graph_launcher_sets() -> None:
    base = {"ROS_LOCALHOST_ONLY": "0", "ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET", "HOME": "/h"}
    assert export_line(graph_env(17, base=base)) == (
        "export ROS_DOMAIN_ID=17 ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST; unset ROS_LOCALHOST_ONLY"
    )
    # --subnet: the default range (unset), and no localhost-only left over
    assert export_line(graph_env(5, localhost=False, base=base)) == (
        "export ROS_DOMAIN_ID=5; unset ROS_AUTOMATIC_DISCOVERY_RANGE ROS_LOCALHOST_ONLY"
    )
    assert hint(graph_env(3, base={})).splitlines()[-1] == (
        "  export ROS_DOMAIN_ID=3 ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST; unset ROS_LOCALHOST_ONLY"
    )

"""The bridge's mapping file, without ROS: the standard rules, and a bad file refused with its reason."""

from __future__ import annotations

from pathlib import Path

import pytest

from fleetbus.publishers.ros.mapping import MappingError, load_mapping


def test_the_standard_mapping_maps_poses_grids_and_hazards() -> None:
    mapping = load_mapping(None)
    assert mapping.rule_for("/amcl_pose", "geometry_msgs/PoseWithCovarianceStamped").event == "localisation"
    assert mapping.rule_for("/map", "nav_msgs/OccupancyGrid").event == "map"
    assert mapping.rule_for("/hazard", "std_msgs/String").event == "hazard"
    assert mapping.rule_for("/chatter", "std_msgs/String") is None, "other strings are recorded as they are"


def test_a_mapping_file_that_is_not_valid_is_refused_saying_what_is_wrong(tmp_path: Path) -> None:
    path = tmp_path / "mapping.yaml"
    path.write_text("rules:\n  - type: my_msgs/Alarm\n    event: alarm\n")
    with pytest.raises(MappingError, match=r"mapping.yaml is not valid: rules.0.event"):
        load_mapping(path)
    with pytest.raises(MappingError, match="cannot read"):
        load_mapping(tmp_path / "missing.yaml")

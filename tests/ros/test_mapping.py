"""The bridge's mapping file, without ROS: topics become events only when a rule names them, a
user's rules come first, and a bad file is refused with its reason."""

from __future__ import annotations

from pathlib import Path

import pytest

from fleetbus.publishers.ros.mapping import MappingError, load_mapping


def test_the_standard_mapping_names_the_conventional_topics_only() -> None:
    mapping = load_mapping(None)
    assert mapping.rule_for("/amcl_pose", "geometry_msgs/PoseWithCovarianceStamped").event == "localisation"
    assert mapping.rule_for("/robot_pose", "geometry_msgs/PoseStamped").event == "localisation"
    assert mapping.rule_for("/map", "nav_msgs/OccupancyGrid").event == "map"
    assert mapping.rule_for("/hazard", "std_msgs/String").event == "hazard"
    assert mapping.rule_for("/chatter", "std_msgs/String") is None, "other strings are recorded as they are"
    assert mapping.rule_for("/move_base_simple/goal", "geometry_msgs/PoseStamped") is None, "a goal"
    assert mapping.rule_for("/move_base/local_costmap/costmap", "nav_msgs/OccupancyGrid") is None
    assert mapping.rule_for("/map", "std_msgs/String") is None, "the topic and the type must both match"


def test_a_users_rules_come_before_the_standard_ones_unless_it_leaves_them_out(tmp_path: Path) -> None:
    path = tmp_path / "mapping.yaml"
    path.write_text(
        "rules:\n"
        "  - {topic: /explorer/*/pose, type: geometry_msgs/PoseStamped, event: localisation}\n"
        "  - {topic: /map, type: nav_msgs/OccupancyGrid, event: hazard, description: header.frame_id}\n"
    )
    mapping = load_mapping(path)
    assert mapping.rule_for("/explorer/front/pose", "geometry_msgs/PoseStamped").event == "localisation"
    assert mapping.rule_for("/map", "nav_msgs/OccupancyGrid").event == "hazard", "the user's rule decides"
    assert mapping.rule_for("/amcl_pose", "geometry_msgs/PoseWithCovarianceStamped") is not None
    path.write_text("standard: false\nrules:\n  - {topic: /odom_pose, type: a/Pose, event: localisation}\n")
    mapping = load_mapping(path)
    assert [rule.topic for rule in mapping.rules] == ["/odom_pose"]


def test_a_mapping_file_that_is_not_valid_is_refused_saying_what_is_wrong(tmp_path: Path) -> None:
    path = tmp_path / "mapping.yaml"
    path.write_text("rules:\n  - {topic: /alarm, type: my_msgs/Alarm, event: alarm}\n")
    with pytest.raises(MappingError, match=r"mapping.yaml is not valid: rules.0.event"):
        load_mapping(path)
    path.write_text("rules:\n  - {type: geometry_msgs/PoseStamped, event: localisation}\n")
    with pytest.raises(MappingError, match=r"rules.0.topic: Field required"):
        load_mapping(path)
    path.write_text("rules:\n  - {topic: '/*', type: geometry_msgs/PoseStamped, event: localisation}\n")
    with pytest.raises(MappingError, match=r"rules.0.topic: String should match"):
        load_mapping(path)
    with pytest.raises(MappingError, match="cannot read"):
        load_mapping(tmp_path / "missing.yaml")

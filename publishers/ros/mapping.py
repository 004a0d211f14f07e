"""The mapping file: which ROS topics (by name, and type) become which fleetbus event.

A topic becomes an event only when a rule names it: a pose on an operator's goal topic is not the
robot's place, a local costmap is not the site's map. The standard rules name the conventional
topics; a user's file adds its own rules before them (the first rule that matches decides), and
``standard: false`` leaves the standard ones out.
"""

from __future__ import annotations

import fnmatch
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError

STANDARD_MAPPING = "standard_mapping.yaml"


class Rule(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    type: str = Field(pattern=r"^[A-Za-z0-9_]+/[A-Za-z0-9_]+$", description="the ROS message type")
    topic: str = Field(
        pattern=r"^/[^*?\[\]]*[A-Za-z0-9_]",
        description="the topic's name, from its root (shell-style `*` and `?` allowed after its first name)",
    )
    event: Literal["localisation", "map", "hazard"]
    pose: str | None = Field(default=None, description="path of a geometry_msgs/Pose in the message")
    description: str | None = Field(default=None, description="path of a hazard's text in the message")

    def matches(self, topic: str, type_name: str) -> bool:
        return type_name == self.type and fnmatch.fnmatchcase(topic, self.topic)


class MappingFile(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    standard: bool = Field(default=True, description="also the standard rules, after these")
    rules: list[Rule] = Field(default_factory=list)


class MappingError(ValueError):
    """A mapping file that cannot be read; the message names the file and what is wrong."""


@dataclass
class Mapping:
    rules: list[Rule]

    def rule_for(self, topic: str, type_name: str) -> Rule | None:
        return next((rule for rule in self.rules if rule.matches(topic, type_name)), None)


def standard_mapping_text() -> str:
    return resources.files(__package__).joinpath(STANDARD_MAPPING).read_text()


def _read(text: str, name: str) -> MappingFile:
    try:
        return MappingFile.model_validate(yaml.safe_load(text) or {})
    except yaml.YAMLError as error:
        raise MappingError(f"the mapping file {name} is not valid YAML: {error}") from None
    except ValidationError as error:
        problems = "; ".join(
            f"{'.'.join(str(p) for p in e['loc'])}: {e['msg']}" for e in error.errors(include_url=False)
        )
        raise MappingError(f"the mapping file {name} is not valid: {problems}") from None


def load_mapping(path: Path | None) -> Mapping:
    """The rules of ``path`` followed by the standard ones shipped with fleetbus (unless the file
    says ``standard: false``); the standard ones alone when ``path`` is None."""
    standard = _read(standard_mapping_text(), f"the standard mapping ({STANDARD_MAPPING})").rules
    if path is None:
        return Mapping(standard)
    try:
        text = path.read_text()
    except OSError as error:
        raise MappingError(f"cannot read the mapping file {path}: {error}") from None
    mine = _read(text, str(path))
    return Mapping(mine.rules + (standard if mine.standard else []))

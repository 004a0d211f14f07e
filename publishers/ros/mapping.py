"""The mapping file: which ROS messages (type, topic pattern) become which fleetbus event."""

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
    topic: str = Field(default="*", description="shell-style pattern of the topics it applies to")
    event: Literal["localisation", "map", "hazard"]
    pose: str | None = Field(default=None, description="path of a geometry_msgs/Pose in the message")
    description: str | None = Field(default=None, description="path of a hazard's text in the message")

    def matches(self, topic: str, type_name: str) -> bool:
        return type_name == self.type and fnmatch.fnmatchcase(topic, self.topic)


class MappingFile(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

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


def load_mapping(path: Path | None) -> Mapping:
    """The rules of ``path``, or the standard ones shipped with fleetbus when ``path`` is None."""
    name = str(path) if path else f"the standard mapping ({STANDARD_MAPPING})"
    try:
        text = path.read_text() if path else standard_mapping_text()
        data = yaml.safe_load(text) or {}
        return Mapping(MappingFile.model_validate(data).rules)
    except OSError as error:
        raise MappingError(f"cannot read the mapping file {name}: {error}") from None
    except yaml.YAMLError as error:
        raise MappingError(f"the mapping file {name} is not valid YAML: {error}") from None
    except ValidationError as error:
        problems = "; ".join(
            f"{'.'.join(str(p) for p in e['loc'])}: {e['msg']}" for e in error.errors(include_url=False)
        )
        raise MappingError(f"the mapping file {name} is not valid: {problems}") from None

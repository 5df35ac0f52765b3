"""Pydantic models of the deployment file (TOML) and its loader.

A bad file raises :class:`ConfigError` with one message naming the file, the key and what was
expected; unknown keys are errors. Paths inside a file are relative to that file.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Annotated, Any, TypeVar

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    ValidationInfo,
    field_validator,
)
from pydantic.functional_validators import AfterValidator

from schemas import describe_validation_error
from services.core.mounts import Geometry
from services.core.world import World
from services.runtime.session import Limits, ZenohSettings

P = TypeVar("P", bound=BaseModel)


class ConfigError(ValueError):
    """A deployment or settings file that cannot be used; the message says where and why."""


def _resolve(path: Path, info: ValidationInfo) -> Path:
    base = (info.context or {}).get("base_dir")
    return path if path.is_absolute() or base is None else (Path(base) / path)


#: A path in a settings file, resolved relative to that file's folder.
RelPath = Annotated[Path, AfterValidator(_resolve)]


class ServiceSettings(BaseModel):
    """Options every ``[services.NAME]`` table accepts."""

    model_config = ConfigDict(extra="forbid")
    process: bool = Field(default=False, description="run this service in its own OS process")

    def part(self, model: type[P]) -> P:
        """The fields of an algorithm's parameter model that these settings extend (a
        service's ``Settings`` subclasses it, so each default is defined once, there)."""
        return model.model_validate({name: getattr(self, name) for name in model.model_fields})


class Deployment(BaseModel):
    """A whole deployment file."""

    model_config = ConfigDict(extra="forbid")
    namespace: str = Field(default="shepherd", pattern=r"^[A-Za-z0-9_\-]+(/[A-Za-z0-9_\-]+)*$")
    zenoh: ZenohSettings = Field(default_factory=ZenohSettings)
    limits: Limits = Field(default_factory=Limits)
    geometry: Geometry = Field(default_factory=Geometry)
    world: World = Field(default_factory=World)
    services: dict[str, dict[str, Any]] = Field(default_factory=dict)
    path: Path | None = Field(default=None, exclude=True)
    settings: dict[str, Any] = Field(default_factory=dict, exclude=True)

    @field_validator("services")
    @classmethod
    def _known_services(cls, services: dict[str, dict[str, Any]]) -> dict[str, dict[str, Any]]:
        from services.runtime.registry import SERVICES
        for name in services:
            if name not in SERVICES:
                raise ValueError(f"unknown service {name!r}; expected one of "
                                 f"{', '.join(sorted(SERVICES))}")
        return services

    def settings_for(self, name: str) -> ServiceSettings:
        return self.settings[name]


def parse_deployment(data: dict[str, Any], path: Path | None = None) -> Deployment:
    """Validate a deployment mapping; raises ConfigError naming the key and what was expected."""
    from services.runtime.registry import load_service

    where = str(path) if path else "<deployment>"
    base_dir = path.parent if path else Path.cwd()
    try:
        dep = Deployment.model_validate(data, context={"base_dir": base_dir})
    except ValidationError as err:
        raise ConfigError(f"{where}: {describe_validation_error(err)}") from None
    zenoh_cfg = dep.zenoh.config_file
    if zenoh_cfg is not None and not zenoh_cfg.is_absolute():
        dep.zenoh.config_file = base_dir / zenoh_cfg
    dep.path = path
    for name, table in dep.services.items():
        settings_model = load_service(name).Settings
        try:
            dep.settings[name] = settings_model.model_validate(
                table or {}, context={"base_dir": base_dir})
        except ValidationError as err:
            what = describe_validation_error(err, f"services.{name}")
            raise ConfigError(f"{where}: {what}") from None
    return dep


def load_deployment(path: str | Path) -> Deployment:
    """Read and validate a TOML deployment file."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as err:
        raise ConfigError(f"{path}: cannot read deployment file: {err.strerror}") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"{path}: not valid TOML: {err}") from None
    return parse_deployment(data, path)

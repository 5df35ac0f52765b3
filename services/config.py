"""Pydantic models of the deployment file (TOML) and its loader.

A bad file raises :class:`ConfigError` with one message naming the file, the key and what was
expected; unknown keys are errors. Paths inside a file are relative to that file.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Annotated, Any

import numpy as np
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    ValidationInfo,
    field_validator,
)
from pydantic.functional_validators import AfterValidator

from services.bus import ZenohSettings
from services.geometry import T_base_camera, T_humanoid_marker
from services.sim.world import World


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


class Geometry(BaseModel):
    """The fixed mounts (DESIGN.md): camera on its robot base, marker on the humanoid. Metres."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    camera_height_m: float = Field(default=0.20, ge=0.0, description="optical centre above floor")
    camera_forward_m: float = Field(default=0.0, description="optical centre ahead of base origin")
    camera_pitch_rad: float = Field(default=0.0, ge=-1.2, le=1.2, description="down is positive")
    marker_centre_height_m: float = Field(default=0.20, gt=0.0)
    marker_back_offset_m: float = Field(default=0.05, ge=0.0,
                                        description="marker centre behind the humanoid origin")
    marker_width_m: float = Field(default=0.050, gt=0.0, description="horizontal diagonal")
    marker_height_m: float = Field(default=0.066, gt=0.0, description="vertical diagonal")

    def marker_points(self) -> np.ndarray:
        """Vertices in the marker frame M, shape (4, 3), ordered left, top, right, bottom (m)."""
        w, h = self.marker_width_m / 2, self.marker_height_m / 2
        return np.array([[-w, 0, 0], [0, h, 0], [w, 0, 0], [0, -h, 0]], dtype=np.float64)

    def T_base_camera(self) -> np.ndarray:
        """4x4 transform camera optical frame -> camera robot base (REP-103 base)."""
        return T_base_camera(self.camera_forward_m, self.camera_height_m, self.camera_pitch_rad)

    def T_humanoid_marker(self) -> np.ndarray:
        """4x4 transform marker frame -> humanoid frame (marker on the humanoid's back)."""
        return T_humanoid_marker(self.marker_back_offset_m, self.marker_centre_height_m)


class Deployment(BaseModel):
    """A whole deployment file."""

    model_config = ConfigDict(extra="forbid")
    namespace: str = Field(default="shepherd", pattern=r"^[A-Za-z0-9_\-]+(/[A-Za-z0-9_\-]+)*$")
    zenoh: ZenohSettings = Field(default_factory=ZenohSettings)
    geometry: Geometry = Field(default_factory=Geometry)
    world: World = Field(default_factory=World)
    services: dict[str, dict[str, Any]] = Field(default_factory=dict)
    path: Path | None = Field(default=None, exclude=True)
    settings: dict[str, Any] = Field(default_factory=dict, exclude=True)

    @field_validator("services")
    @classmethod
    def _known_services(cls, services: dict[str, dict[str, Any]]) -> dict[str, dict[str, Any]]:
        from services.registry import SERVICES
        for name in services:
            if name not in SERVICES:
                raise ValueError(f"unknown service {name!r}; expected one of "
                                 f"{', '.join(sorted(SERVICES))}")
        return services

    def settings_for(self, name: str) -> ServiceSettings:
        return self.settings[name]


def _describe(err: ValidationError, prefix: str = "") -> str:
    first = err.errors()[0]
    key = ".".join(str(p) for p in (*([prefix] if prefix else []), *first["loc"]))
    got = first.get("input")
    got_text = "" if first["type"] == "missing" or isinstance(got, dict) else f" (got {got!r})"
    msg = first["msg"].removeprefix("Value error, ")
    if first["type"] == "extra_forbidden":
        msg = "unknown key"
    return f"{key or '(top level)'}: {msg}{got_text}"


def parse_deployment(data: dict[str, Any], path: Path | None = None) -> Deployment:
    """Validate a deployment mapping; raises ConfigError naming the key and what was expected."""
    from services.registry import load_service

    where = str(path) if path else "<deployment>"
    base_dir = path.parent if path else Path.cwd()
    try:
        dep = Deployment.model_validate(data, context={"base_dir": base_dir})
    except ValidationError as err:
        raise ConfigError(f"{where}: {_describe(err)}") from None
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
            raise ConfigError(f"{where}: {_describe(err, f'services.{name}')}") from None
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

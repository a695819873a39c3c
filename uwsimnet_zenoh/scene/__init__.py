"""Scene files: the XML vocabulary (UWSim-NET legacy + native extensions) and the validated models."""

from .load import SceneError, load_scene, load_scene_text
from .model import (
    BROADCAST,
    Channel,
    Device,
    Environment,
    ErrorModel,
    Flow,
    MacSpec,
    ModelSpec,
    Scene,
    Simulation,
    Tracing,
    Vehicle,
    Waypoint,
)

__all__ = [
    "BROADCAST",
    "Channel",
    "Device",
    "Environment",
    "ErrorModel",
    "Flow",
    "MacSpec",
    "ModelSpec",
    "Scene",
    "SceneError",
    "Simulation",
    "Tracing",
    "Vehicle",
    "Waypoint",
    "load_scene",
    "load_scene_text",
]

"""Lights of rose's shading model (see rose_usd.render.scene): an ambient term and point lights.

In a stage they are UsdLux prims under /World/Scene/Lights: a DomeLight (ambient) and point-like
SphereLights; ``inputs:intensity * inputs:color`` is read as linear RGB (radiant intensity for
point lights, irradiance factor for the dome).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class PointLight:
    position_m: tuple[float, float, float]
    """Light position in the world [m]."""
    intensity: tuple[float, float, float]
    """Linear RGB radiant intensity; irradiance at distance r is intensity * cos / r^2."""


@dataclass(frozen=True)
class Lighting:
    ambient: tuple[float, float, float] = (1.0, 1.0, 1.0)
    """Linear RGB ambient irradiance factor (radiance = albedo * ambient, no occlusion)."""
    points: tuple[PointLight, ...] = ()

    @classmethod
    def unlit(cls) -> "Lighting":
        """Radiance = albedo: for meshes whose colors already hold the video's lighting."""
        return cls(ambient=(1.0, 1.0, 1.0), points=())

    def to_json(self) -> dict:
        return {
            "ambient": list(self.ambient),
            "points": [{"position_m": list(p.position_m), "intensity": list(p.intensity)} for p in self.points],
        }

    @classmethod
    def from_json(cls, data: dict) -> "Lighting":
        return cls(
            ambient=tuple(float(v) for v in data["ambient"]),
            points=tuple(
                PointLight(tuple(map(float, p["position_m"])), tuple(map(float, p["intensity"])))
                for p in data.get("points", [])
            ),
        )

"""Light sources, one module per kind, chosen by the ``type`` of their TOML table.

``directional`` (sun.py) and ``point`` (point.py); environment maps and skies (popvol.envmap)
become several directional lights. base.py holds the interface every kind implements.
"""
from .base import HandOver, Light, LightDomain
from .point import PointLight, SphericalDomain
from .sun import DirectionalLight, SunDomain

#: The light classes by their TOML ``type``.
LIGHTS: dict[str, type[Light]] = {cls.type: cls for cls in (DirectionalLight, PointLight)}

__all__ = ["Light", "LightDomain", "HandOver", "DirectionalLight", "PointLight", "SunDomain",
           "SphericalDomain", "LIGHTS"]

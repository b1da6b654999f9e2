"""Write examples/envmaps/dusk.exr: a small procedural HDR lat-long environment (128 x 64,
Mitsuba's envmap convention, see popvol/envmap.py) for examples/demo_envmap.toml.

    python scripts/make_envmap.py

A low warm sun (elevation 10 degrees, a disc of a few texels, irradiance (2.6, 1.9, 1.2)), a sky that is
orange near the sun's horizon and deep blue overhead and opposite, soft cloud bands, and a dark
ground. Deterministic: the same file every run.
"""
from pathlib import Path

import numpy as np

from popvol.envmap import EnvMap, integral, texel_geometry
from popvol.io.images import write_exr

OUT = Path(__file__).resolve().parents[1] / "examples" / "envmaps" / "dusk.exr"


def dusk(height: int = 64) -> np.ndarray:
    d, omega = texel_geometry(height, 2 * height)            # (H, W, 3) texel directions
    # the sun 10 degrees up, to the front left of examples/demo_envmap.toml's camera (+z)
    sun = np.array([-np.cos(np.radians(10)) * np.sin(np.radians(50)), np.sin(np.radians(10)),
                    np.cos(np.radians(10)) * np.cos(np.radians(50))])
    el = np.clip(d[..., 1], 0.0, 1.0)
    toward_sun = np.clip(d @ sun, 0.0, 1.0)
    zenith, horizon, glow = np.array([0.05, 0.10, 0.30]), np.array([0.30, 0.30, 0.40]), np.array([1.2, 0.55, 0.2])
    t = np.sqrt(el)[..., None]
    sky = (1 - t) * horizon + t * zenith + glow * (toward_sun ** 8 * (1 - el) ** 2)[..., None]
    # soft cloud bands: brighter, greyer streaks in the upper sky
    u = np.arctan2(d[..., 0], -d[..., 2])
    bands = 0.5 + 0.5 * np.sin(7 * u + 11 * el) * np.sin(3 * u - 5 * el + 1.0)
    cloud = (np.clip(bands - 0.55, 0, None) * 2.0 * np.sin(np.pi * el))[..., None]
    sky = sky * (1 - cloud) + cloud * (0.4 + 0.8 * toward_sun[..., None] ** 4) * np.array([1.0, 0.8, 0.7])
    rad = np.where(d[..., 1:2] >= 0, sky, np.array([0.02, 0.018, 0.015]))
    # the sun: the texels within ~2 texels of its direction, irradiance [2.6, 1.9, 1.2] in all
    disc = d @ sun > np.cos(1.5 * np.pi / height)
    E = np.array([2.6, 1.9, 1.2])
    rad[disc] += E / omega[disc].sum()
    return rad.astype(np.float32)


if __name__ == "__main__":
    rad = dusk()
    OUT.parent.mkdir(parents=True, exist_ok=True)
    write_exr(OUT, rad)
    print(OUT, rad.shape, "fluence", integral(EnvMap(rad, "dusk")))

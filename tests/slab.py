"""Dense media as popvol scenes, for the dense-media tests and scripts/dense_slab.py: a front-lit
slab, whose reflected radiance at the image centre is the plane-parallel albedo problem that
tests/montecarlo.py's half_space_mc solves independently, and a cube filling its grid, whose
single scattering cube_single_scattering integrates independently of popvol's fields, and a wide
slab whose fluence inside is what slab_fluence_mc estimates."""
import numpy as np

import popvol
from popvol import hg

from popvol.camera import Camera
from popvol.lights import DirectionalLight
from popvol.medium import Medium
from popvol.method import Method
from popvol.scene import Scene

#: the sun's travel direction: from behind the camera, 148 degrees of scattering toward it
LIGHT = np.array([0.3, -0.4, -1.0]) / np.linalg.norm([0.3, -0.4, -1.0])
VIEW = np.array([0.0, 0.0, 1.0])    # toward the camera, straight up
ALBEDO, G = 0.9, 0.5
N = 16      # the slab is N x N x N/4 voxels of 1/8
VOXEL = 1.0 / 8


def slab_depth(tau_voxel: float, n: int = N) -> float:
    """The slab's optical thickness when one voxel is ``tau_voxel`` mean free paths."""
    return tau_voxel * (n // 4)


def slab_scene(tau_voxel: float, resolution: int, n: int = N, pad: int = 0, albedo: float = ALBEDO,
               g: float = G, layers: int | None = None) -> Scene:
    """A slab of unit density, n x n x ``layers`` voxels of 1/8 (``tau_voxel`` mean free paths
    each; layers n/4 by default), its top face z = 0 seen straight down by a 16 x 16 camera
    whose centre pixels see only it. ``pad``: layers of empty voxels above it, as a volume read
    from a file has (the density then ramps from 1 to 0 between z = -1/16 and 1/16, the centres
    of the top full voxel and of the first empty one: the same optical depth, and a
    plane-parallel medium's reflection depends on its optical depths alone). ``albedo`` and
    ``g``: the medium's (ALBEDO and G by default)."""
    layers = n // 4 if layers is None else layers
    rho = np.zeros((n, n, layers + pad), np.float32)
    rho[:, :, :layers] = 1.0
    h = VOXEL
    origin = np.array([-n / 16 + h / 2, -n / 16 + h / 2, -layers * h + h / 2])
    med = Medium(rho, h, origin, scale=tau_voxel / h, albedo=albedo, g=g, source="slab")
    cam = Camera([0.0, 0.0, 4.0], [0.0, 0.0, 0.0], [0, 1, 0], 6.0, 16, 16)
    return Scene(med, [DirectionalLight(LIGHT, 1.0)], cam, np.zeros(3), Method(resolution=resolution))


def centre_radiance(image: np.ndarray) -> float:
    """The mean red radiance of the 4 x 4 centre pixels (they see the slab's middle)."""
    return float(image[6:10, 6:10, 0].mean())


def dense_cube_scene(tau_voxel, light=None, n=8):
    """A cube of unit density filling its n^3 grid, ``tau_voxel`` mean free paths per voxel, so
    its faces are the grid's own edges, seen from a corner (three faces show) and lit by
    ``light``, by default a sun through the three faces in view."""
    med = Medium(np.ones((n, n, n), np.float32), 1.0 / n, np.full(3, 0.5 / n), scale=tau_voxel * n, albedo=0.9,
                 g=0.5, source="cube")
    cam = Camera([1.9, 1.6, 2.4], [0.5, 0.5, 0.5], [0, 1, 0], 40.0, 24, 20)
    light = light or DirectionalLight([-0.3, -0.8, -0.5], [1.0, 0.8, 0.6])
    return Scene(med, [light], cam, np.zeros(3), Method(resolution=16, tolerance=1e-6, gather=0))


def cube_single_scattering(scene, n_tau=20000):
    """The single scattering of a uniform cube at the pixel centres, independently of popvol's
    fields: L = int exp(-tau_v) Lambda E f_hg(mu; g) exp(-sigma_t s(x)) dtau_v along the camera
    ray, s(x) the distance from x back to the cube's surface along the light (its unscattered
    light by Beer-Lambert), by a midpoint rule in the camera's optical depth over its first 60
    mean free paths."""
    med, light, cam = scene.medium, scene.lights[0], scene.camera
    lo, hi = med.bounds
    fwd, right, up = cam.basis()
    tan_half = np.tan(np.radians(cam.fov) / 2)
    sigma = float(med.scale[0])
    back = -light.direction
    out = np.zeros((cam.height, cam.width, 3))
    for py in range(cam.height):
        for px in range(cam.width):
            sx = (2 * (px + 0.5) / cam.width - 1) * tan_half * cam.width / cam.height
            sy = (1 - 2 * (py + 0.5) / cam.height) * tan_half
            d = fwd + sx * right + sy * up
            d /= np.linalg.norm(d)
            with np.errstate(divide="ignore", invalid="ignore"):
                ta, tb = (lo - cam.origin) / d, (hi - cam.origin) / d
            t0, t1 = max(0.0, np.nanmax(np.minimum(ta, tb))), np.nanmin(np.maximum(ta, tb))
            if t1 <= t0:
                continue
            tau_max = min(sigma * (t1 - t0), 60.0)
            tau = (np.arange(n_tau) + 0.5) / n_tau * tau_max
            x = cam.origin + (t0 + tau[:, None] / sigma) * d
            with np.errstate(divide="ignore"):
                s = np.min(np.where(back > 0, (hi - x) / back, np.where(back < 0, (lo - x) / back, np.inf)), axis=1)
            out[py, px] = (np.sum(np.exp(-tau - sigma * s)) * tau_max / n_tau * med.albedo[0]
                           * hg.f_hg(-(d @ light.direction), med.g) * light.irradiance)
    return out


def wide_slab_fluence(tau_voxel: float, albedo: float, g: float, n: int = 48, layers: int = 4,
                      pad: int = 2) -> tuple[np.ndarray, float]:
    """:func:`slab_scene`, n x n x ``layers`` voxels (wide enough to stand for a plane-parallel
    slab at its centre), lit by LIGHT at unit irradiance and solved at n cells: (its fluence per
    unit irradiance, unscattered and scattered, at the centre's voxels from the lit face down,
    float64 (layers,); the cap on light transport, Medium.transport_depth_cap)."""
    scene = slab_scene(tau_voxel, n, n=n, pad=pad, albedo=albedo, g=g, layers=layers)
    sol = popvol.solve(scene)
    c = slice(n // 2 - 2, n // 2 + 2)
    phi = sol.direct[0, 0, c, c, :layers] + sol.phid[0, 0, c, c, :layers]
    return phi.mean(axis=(0, 1), dtype=np.float64)[::-1], scene.medium.transport_depth_cap()

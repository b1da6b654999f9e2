"""A front-lit slab as a popvol scene, for the dense-media test and scripts/dense_slab.py: its
reflected radiance at the image centre is the plane-parallel albedo problem that
tests/montecarlo.py's half_space_mc solves independently."""
import numpy as np

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


def slab_scene(tau_voxel: float, resolution: int, n: int = N, pad: int = 0) -> Scene:
    """A slab of unit density, n x n x n/4 voxels of 1/8 (``tau_voxel`` mean free paths each),
    its top face z = 0 seen straight down by a 16 x 16 camera whose centre pixels see only it.
    ``pad``: layers of empty voxels above it, as a volume read from a file has (the density then
    ramps from 1 to 0 between z = -1/16 and 1/16, the centres of the top full voxel and of the
    first empty one: the same optical depth, and a plane-parallel medium's reflection depends on
    its optical depths alone)."""
    rho = np.zeros((n, n, n // 4 + pad), np.float32)
    rho[:, :, :n // 4] = 1.0
    h = VOXEL
    origin = np.array([-n / 16 + h / 2, -n / 16 + h / 2, -n / 32 + h / 2])
    med = Medium(rho, h, origin, scale=tau_voxel / h, albedo=ALBEDO, g=G, source="slab")
    cam = Camera([0.0, 0.0, 4.0], [0.0, 0.0, 0.0], [0, 1, 0], 6.0, 16, 16)
    return Scene(med, [DirectionalLight(LIGHT, 1.0)], cam, np.zeros(3), Method(resolution=resolution))


def centre_radiance(image: np.ndarray) -> float:
    """The mean red radiance of the 4 x 4 centre pixels (they see the slab's middle)."""
    return float(image[6:10, 6:10, 0].mean())

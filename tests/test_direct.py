"""experimental.direct = "voxels": a sun's unscattered light on a domain of its own as fine as the
medium's voxels, against Beer-Lambert written here (exp(-sigma_t s), s the distance from a voxel
centre back to a uniform cube's surface along the light; independent of popvol's fields)."""
import numpy as np

import popvol
from popvol.camera import Camera
from popvol.lights import DirectionalLight
from popvol.medium import Medium
from popvol.method import Method
from popvol.scene import Scene

N, SIGMA = 32, 16.0                     # half a mean free path per voxel
LIGHT = np.array([0.3, -0.8, -0.5]) / np.linalg.norm([0.3, -0.8, -0.5])


def cube():
    return Medium(np.ones((N, N, N), np.float32), 1.0 / N, np.full(3, 0.5 / N), scale=SIGMA, albedo=0.9, g=0.5,
                  source="cube")


def beer_lambert(med):
    lo, hi = med.bounds
    x = med.origin + np.indices(med.shape).reshape(3, -1).T * med.voxel_size
    back = -LIGHT
    with np.errstate(divide="ignore"):
        s = np.min(np.where(back > 0, (hi - x) / back, np.where(back < 0, (lo - x) / back, np.inf)), axis=1)
    return np.exp(-SIGMA * s).reshape(med.shape)


def direct_ratio(direct: str, resolution: int) -> np.ndarray:
    """popvol's phi_dir over Beer-Lambert's at the voxels where the latter is above 0.01."""
    med = cube()
    cam = Camera([1.9, 1.6, 2.4], [0.5, 0.5, 0.5], [0, 1, 0], 40.0, 8, 8)
    scene = Scene(med, [DirectionalLight(LIGHT, 1.0)], cam, np.zeros(3), Method(resolution=resolution, direct=direct))
    got = popvol.solve(scene).direct[0, 0]
    exact = beer_lambert(med)
    lit = exact > 1e-2
    return got[lit] / exact[lit]


def test_the_unscattered_light_on_voxel_fine_cells_is_beer_lambert_where_the_walk_is_coarse():
    """At 16 cells (two voxels per cell) the walk's own cells put phi_dir at the voxels at a
    median x1.54 of Beer-Lambert, its 95th percentile x5.4 (the light interpolated between
    cells a mean free path apart); on a domain as fine as the voxels x1.08 and x1.33, as the
    walk's cells do at 64 (x1.06 and x1.25)."""
    fine, coarse = direct_ratio("voxels", 16), direct_ratio("domain", 16)
    assert abs(np.median(fine) - 1.0) < 0.1 and np.percentile(fine, 95) < 1.4
    assert np.median(coarse) > 1.4 and np.percentile(coarse, 95) > 4.0      # what "voxels" mends


def test_voxel_fine_unscattered_light_changes_nothing_where_the_walk_is_as_fine():
    """Where the walk's cells are no wider than the voxels there is no second domain."""
    np.testing.assert_array_equal(direct_ratio("voxels", 64), direct_ratio("domain", 64))

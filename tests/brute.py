"""Brute-force helpers for the single-scattering oracles of test_render.py and test_point.py,
written independently of popvol's kernels (scipy's interpolation, NumPy ray-box clipping)."""
import numpy as np
from scipy.ndimage import map_coordinates


def density_sampler(med):
    """density(p) at world points p (..., 3): scipy's linear interpolation, clamped to the edge
    inside the medium's cells [-1/2, n - 1/2] per axis, 0 outside."""
    n = np.asarray(med.shape)

    def density(p):
        q = (p - med.origin) / med.voxel_size
        inside = np.all((q >= -0.5) & (q <= n - 0.5), axis=-1)
        q = np.clip(q, 0, n - 1)
        v = map_coordinates(med.density, q.reshape(-1, 3).T, order=1, mode="nearest").reshape(q.shape[:-1])
        return np.where(inside, v, 0.0)
    return density


def view_march(scene, n_steps):
    """Camera rays through pixel centres, clipped to the medium's box and cut into n_steps equal
    segments. Returns d (H, W, 3) unit directions, pts (H, W, S, 3) segment midpoints and dt
    (H, W, 1) segment lengths."""
    med, cam = scene.medium, scene.camera
    lo, hi = med.bounds
    fwd, right, up = cam.basis()
    t = np.tan(np.radians(cam.fov) / 2)
    px, py = np.meshgrid(np.arange(cam.width) + 0.5, np.arange(cam.height) + 0.5)
    sx = (2 * px / cam.width - 1) * t * cam.width / cam.height
    sy = (1 - 2 * py / cam.height) * t
    d = fwd + sx[..., None] * right + sy[..., None] * up
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    with np.errstate(divide="ignore", invalid="ignore"):
        ta, tb = (lo - cam.origin) / d, (hi - cam.origin) / d
    t0 = np.clip(np.nanmax(np.minimum(ta, tb), axis=-1), 0, None)
    t1 = np.maximum(np.nanmin(np.maximum(ta, tb), axis=-1), t0)
    ts = t0[..., None] + (np.arange(n_steps) + 0.5) / n_steps * (t1 - t0)[..., None]   # (H, W, S)
    dt = ((t1 - t0) / n_steps)[..., None]
    pts = cam.origin + ts[..., None] * d[..., None, :]
    return d, pts, dt

"""The compiled ray builder (mutloc.core.rays) against a NumPy reference written here from the lenses' public
interface (unprojection, projection Jacobian) and the definition of a ray frame: two tangent rows weighted by
the lens's Jacobian, the ray, the camera's centre, all in the robot's frame."""

from __future__ import annotations

import numpy as np
import pytest

from mutloc.core.geometry import so3_exp
from mutloc.core.pose import Pose
from mutloc.core.rays import lens_table, pair_rays, ray_frames
from mutloc.core.rig import Mount
from mutloc.errors import ObservationError
from mutloc.sim.bodies import random_lens


def _reference(mount, uv):
    """Ray frames by the definition, one row at a time in NumPy."""
    cam, R, t = mount.camera, mount.pose.R, mount.pose.t
    out = np.empty((len(uv), 4, 3))
    for i, p in enumerate(uv):
        b = np.asarray(cam.pixels_to_bearings(p), float)
        b = b / np.linalg.norm(b)
        # any orthonormal tangent basis: the residual's rows A E do not depend on the choice
        a = np.eye(3)[np.argmin(np.abs(b))]
        e1 = np.cross(b, a)
        e1 /= np.linalg.norm(e1)
        E = np.array([e1, np.cross(b, e1)])
        _, J = cam.project_jacobian(b)
        W = (J @ E.T) @ E  # = J projected on the tangent plane: J (I - b b^T)
        out[i, :2] = W @ R.T
        out[i, 2] = R @ b
        out[i, 3] = t
    return out


def _mount(rng, model, name="c"):
    lens = random_lens(rng, model)
    R = so3_exp(rng.normal(0, 1.0, 3))
    return Mount(name, lens, Pose(R, rng.normal(0, 0.3, 3)))


def _pixels(rng, mount, n):
    """Pixels of directions all over the lens's field (fisheye and omni: past 90 degrees off the axis)."""
    cam = mount.camera
    uv = []
    while len(uv) < n:
        th = rng.uniform(0, min(cam.max_angle, np.pi) * 0.97)
        ph = rng.uniform(0, 2 * np.pi)
        X = np.array([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)]) * rng.uniform(0.5, 8)
        p = np.asarray(cam.project(X), float)
        if np.all(np.isfinite(p)) and cam.in_image(p) and np.all(np.isfinite(np.asarray(cam.pixels_to_bearings(p),
                                                                                           float))):
            uv.append(p)
    return np.array(uv)


@pytest.mark.parametrize("model", ["pinhole", "fisheye", "omni"])
def test_ray_frames_match_the_definition(model):
    rng = np.random.default_rng({"pinhole": 1, "fisheye": 2, "omni": 3}[model])
    for _ in range(5):
        mount = _mount(rng, model)
        uv = _pixels(rng, mount, 40)
        b, f = ray_frames(mount, uv)
        ref = _reference(mount, uv)
        scale = np.abs(ref[:, :2]).max()
        np.testing.assert_allclose(f[:, :2], ref[:, :2], atol=1e-11 * scale)
        np.testing.assert_allclose(f[:, 2], ref[:, 2], atol=1e-12)
        np.testing.assert_allclose(f[:, 3], ref[:, 3], atol=0)
        np.testing.assert_array_equal(b, f[:, 2])
        if model != "pinhole":
            th = np.arccos(np.clip(np.einsum("ij,j->i", f[:, 2], mount.pose.R[:, 2]), -1, 1))
            assert np.degrees(th).max() > 90.0  # rays behind the camera's plane were built too


def test_pair_rays_route_each_row_to_its_camera():
    """Rows of three cameras (each lens model) interleaved: each row's frame is its own camera's."""
    rng = np.random.default_rng(4)
    mounts = {f"r/{m}": (0, _mount(rng, m, m)) for m in ("pinhole", "fisheye", "omni")}
    keys, uv = [], []
    for k, (_, mount) in mounts.items():
        for p in _pixels(rng, mount, 7):
            keys.append(k)
            uv.append(p)
    order = rng.permutation(len(keys))
    keys = [keys[i] for i in order]
    uv = np.array(uv)[order]
    b, f = pair_rays(lens_table(mounts), keys, uv)
    for i, k in enumerate(keys):
        ref = _reference(mounts[k][1], uv[i:i + 1])[0]
        np.testing.assert_allclose(f[i], ref, atol=1e-9 * max(1.0, np.abs(ref).max()))
    # a plain mounts dict gives the same
    np.testing.assert_array_equal(pair_rays(mounts, keys, uv)[1], f)


def test_a_pixel_the_lens_does_not_image_is_named():
    rng = np.random.default_rng(5)
    mount = _mount(rng, "fisheye")
    uv = _pixels(rng, mount, 3)
    uv[1] = [5000.0, 5000.0]  # far outside the image circle
    with pytest.raises(ObservationError, match=r"obs\[1\]: pixel \(5000.00, 5000.00\) is outside what the fisheye"):
        ray_frames(mount, uv, lambda i: f"obs[{i}]")

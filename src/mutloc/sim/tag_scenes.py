"""Rendered test scenes for tag detectors: many tags, partial views, camera-like images.

:func:`tag_scene` places ``n_tags`` printed tags (cards of one family, random
ids) in front of one camera in a textured room: 1.2-3.5 m away, tilted up to
``max_tilt_deg`` and rolled at random, some straddling the image border and
some partly hidden behind a floating sphere.  The image comes from
:func:`mutloc.sim.render.render` (linear light, optical blur, sRGB encoding,
noise, optional JPEG), the truth from the same geometry: each tag's corners
projected through the camera (mutloc's pixel convention, OpenCV corner order).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ..core.camera import Camera
from ..core.geometry import so3_exp
from ..core.pose import Pose
from ..core.rig import Marker, Robot
from ..detect.tags import canonical_family, tag_id_count, tag_spec
from ..errors import InputError
from .render import render, room_around
from .world import Sensor, World, WorldRobot, camera_to_world_facing, tag_corners

__all__ = ["TagScene", "tag_scene", "scene_camera"]

# Fraction of tags placed across the image border, and partly behind a sphere.
_BORDER_FRACTION = 0.2
_OCCLUDED_FRACTION = 0.2
_OCCLUDER_RADIUS = 0.04


@dataclass
class TagScene:
    """One rendered image and its truth."""

    image: np.ndarray                 # uint8 BGR
    markers: dict[str, Marker]        # one tag marker per placed tag (names T0, T1, ...)
    corners: dict[str, np.ndarray]    # true corners (4, 2) per marker, pixels (may lie outside the image)
    in_frame: dict[str, bool]         # all four corners inside the image
    occluded: dict[str, bool]         # a sphere was placed over part of the tag
    camera: Camera


def scene_camera(width: int = 960, height: int = 540, f: float | None = None) -> Camera:
    """A pinhole camera of the given size; focal ``f`` defaults to 800 px at 960 wide (62 deg across)."""
    f = 800.0 * width / 960.0 if f is None else float(f)
    K = np.array([[f, 0.0, (width - 1) / 2.0], [0.0, f, (height - 1) / 2.0], [0.0, 0.0, 1.0]])
    return Camera(K, np.zeros(5), (width, height))


def tag_scene(seed: int, *, n_tags: int = 12, family: str = "tag36h11", size: float = 0.12,
              distance: tuple[float, float] = (1.2, 3.5), max_tilt_deg: float = 50.0,
              camera: Camera | None = None, psf_sigma_px: float = 0.7, noise_sigma: float = 2.0,
              jpeg_quality: int | None = None, partial: bool = True, exposure: float = 1.0) -> TagScene:
    """Render ``n_tags`` tags of ``family`` in front of a camera (see the module docstring).

    ``partial=False`` keeps every tag inside the image and unoccluded;
    ``exposure`` scales the light reaching the sensor (0.2: a dim scene).
    Deterministic in ``seed``.
    """
    if not isinstance(n_tags, int) or n_tags < 1:
        raise InputError(f"n_tags must be a positive integer, got {n_tags!r}")
    fam = canonical_family(family)
    cam = camera if camera is not None else scene_camera()
    w, h = cam.size  # type: ignore[misc]
    rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, 7211])
    probe = Marker("probe", "probe", np.zeros(3), tag={"family": fam, "id": 0, "size": size})
    tag_spec(probe)  # validates family and size
    n_ids = tag_id_count(fam)
    ids = rng.choice(n_ids, size=min(n_tags, n_ids), replace=False)
    T_wc = camera_to_world_facing((0.0, 0.0, 1.0))
    fx = float(cam.K[0, 0])

    robots: dict[str, WorldRobot] = {"cam": WorldRobot(Robot("cam", cam, {}), T_wc, body=False)}
    markers: dict[str, Marker] = {}
    placed: list[tuple[np.ndarray, float]] = []  # image centre, image radius
    occluded: dict[str, bool] = {}
    for i, tid in enumerate(ids):
        for _attempt in range(50):
            z = rng.uniform(*distance)
            r_px = 0.75 * size * fx / z  # card half-diagonal, roughly
            border = partial and rng.uniform() < _BORDER_FRACTION
            if border:  # centre within half a tag of an image edge
                edge = rng.integers(4)
                u = rng.uniform(0, w - 1) if edge < 2 else (0 if edge == 2 else w - 1) + rng.uniform(-0.4, 0.4) * r_px
                v = rng.uniform(0, h - 1) if edge >= 2 else (0 if edge == 0 else h - 1) + rng.uniform(-0.4, 0.4) * r_px
            else:
                u = rng.uniform(r_px, w - 1 - r_px)
                v = rng.uniform(r_px, h - 1 - r_px)
            c = np.array([u, v])
            if all(np.linalg.norm(c - pc) > 1.05 * (r_px + pr) for pc, pr in placed):
                break
        else:
            continue
        placed.append((c, r_px))
        X_c = z * np.array([(u - cam.K[0, 2]) / fx, (v - cam.K[1, 2]) / float(cam.K[1, 1]), 1.0])
        # Tag frame = the tag robot's frame: z away from the camera (seen printed side on), tilted, rolled.
        axis = np.array([*rng.normal(size=2), 0.0])
        tilt = axis / max(float(np.linalg.norm(axis)), 1e-12) * np.radians(rng.uniform(0, max_tilt_deg))
        R_ct = so3_exp(tilt) @ so3_exp([0.0, 0.0, rng.uniform(-np.pi, np.pi)])
        name = f"T{i}"
        m = Marker(name, name, np.zeros(3), tag={"family": fam, "id": int(tid), "size": size,
                                                 "rotation": [0.0, 0.0, 0.0]})
        markers[name] = m
        robots[name] = WorldRobot(Robot(name, cam, {name: m}), T_wc @ Pose(R_ct, X_c), body=False)
        occ = partial and not border and rng.uniform() < _OCCLUDED_FRACTION
        occluded[name] = bool(occ)
        if occ:  # a sphere in front of one side of the tag, covering part of it
            ang = rng.uniform(0, 2 * np.pi)
            off = 0.5 * size * np.array([np.cos(ang), np.sin(ang), 0.0])
            zc = 0.75 * z
            X_o = (X_c + off) * zc / z
            ball = Marker(f"O{i}", f"O{i}", np.zeros(3), color=tuple(int(x) for x in rng.integers(40, 220, 3)),
                          extra={"radius": _OCCLUDER_RADIUS})
            robots[f"O{i}"] = WorldRobot(Robot(f"O{i}", cam, {f"O{i}": ball}), T_wc @ Pose(np.eye(3), X_o),
                                         body=False)
    world = World(robots=robots, room=room_around([T_wc.t, T_wc.apply([0.0, 0.0, distance[1]])], int(seed)),
                  sensor=dataclasses.replace(Sensor(), psf_sigma_px=float(psf_sigma_px), exposure=float(exposure)))
    image = render(world, "cam", seed=int(seed), noise_sigma=float(noise_sigma), jpeg_quality=jpeg_quality)
    T_cw = T_wc.inverse()
    corners: dict[str, np.ndarray] = {}
    in_frame: dict[str, bool] = {}
    for name, m in markers.items():
        X = robots[name].pose_at(0.0).apply(tag_corners(m))
        uv = cam.project(T_cw.apply(X))
        corners[name] = uv
        in_frame[name] = bool(np.all((uv >= -0.5) & (uv <= np.array([w - 0.5, h - 0.5]))))
    return TagScene(image, markers, corners, in_frame, occluded, cam)


"""A second renderer: mutloc's worlds drawn by Blender's Cycles path tracer, with exact truth.

mutloc's own renderer (:mod:`mutloc.sim.render`) wrote the images its
detectors were tuned on; a detector judged only there may have learnt that
renderer.  This module draws the *same* :class:`~mutloc.sim.world.World`
(the same primitives, from :func:`~mutloc.sim.render.scene_primitives`:
room with its textures, robot bodies, balls, props) with Cycles on the CPU:
a physically based light transport with soft and hard shadows, bounce
light, glossy highlights that reflect the room, a pixel filter and a
denoiser, none of which mutloc's renderer has.

- :func:`scene_spec` turns a world into a JSON-able spec (objects, light,
  cameras) and writes the room's textures as PNG files;
- :func:`render_spec` runs :mod:`mutloc.sim.blender_scene` on it in an
  interpreter that has the ``bpy`` wheel (``pip install "mutloc[render]"``
  in a virtual environment of its own: bpy 5.0 pins numpy < 2) and returns
  the images;
- :func:`ball_truth` gives what a detector should report: each ball's true
  projected centre (the projection of the sphere's centre), its apparent
  radius and the share of its disc hidden by other objects (rays cast
  against the same geometry, :func:`~mutloc.sim.render.ball_visibility`).

Light: the world's point light becomes a Cycles point light at the same
place and colour whose power gives a matte surface facing it at the robots'
distance the radiance mutloc's renderer gives it (``albedo * intensity``);
a hard light (``shadows``) is a 5 mm source, a soft one 15 cm.  The ambient
term becomes an area light under the ceiling.  Balls are matte
(``world.ball_finish`` None) or glossy plastic; props listed in ``metal``
are polished metal (lights' and balls' mounting rods).

Cameras: pinhole (OpenCV ``K``, no distortion), or the ideal equidistant
fisheye (:class:`~mutloc.core.lenses.FisheyeCamera` with k1..k4 = 0, ``r = f
* theta``, centred, square pixels) of a robot with several cameras (views
``ROBOT/CAMERA``): Cycles' panoramic camera, ``FISHEYE_EQUIDISTANT`` for a
square image (its ``fisheye_fov`` spans the image's width, ``W / f``; black
outside that circle) and ``FISHEYE_LENS_POLYNOMIAL`` (``theta = r / f`` on the
sensor) for any other.  Blender's image centre is matched to OpenCV's
pixel-centre convention, so a point projects where the camera's ``project``
puts it (measured: ``bench/check_blender_fisheye.py``).

Tags (printed cards) are textured quads drawn with the nearest texel; the
card is matte paper, both sides printed (mutloc's renderer draws the back
blank: a card is seen from behind only through the robot it is stuck on).
"""

from __future__ import annotations

import importlib.util
import json
import math
import os
import subprocess
import sys
import tempfile
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from ..core.pose import Pose
from ..core.rig import CAMERA_SEPARATOR
from ..errors import InputError, MissingExtraError
from .render import ball_visibility, project_markers, scene_primitives, srgb_to_linear
from .world import World, ball_radius, room_textures, tag_image

__all__ = ["BLENDER_SCRIPT", "ball_truth", "blender_python", "render_spec", "scene_spec"]

#: The script that builds and renders a spec inside Blender's Python.
BLENDER_SCRIPT = Path(__file__).with_name("blender_scene.py")
# Source radii (m) of the key light: hard (shadows on) and soft.
_HARD_RADIUS, _SOFT_RADIUS = 0.005, 0.15
# Area of the fill light under the ceiling (m) and its gain over the ambient term (the room's own
# walls then return some of it).
_FILL_SIZE = (3.0, 3.0)
_FILL_GAIN = 2.0


def _lin_rgb(rgb255: Sequence[float]) -> list[float]:
    return [float(x) for x in srgb_to_linear(np.asarray(rgb255, float) / 255.0)]


def _texture_files(world: World, folder: Path) -> dict[str, tuple[str, tuple[float, float]]]:
    """``{surface: (png path, uv scale)}`` of the room's textures, written once into ``folder``."""
    room = world.room
    if room is None:
        return {}
    folder.mkdir(parents=True, exist_ok=True)
    key = f"room_{room.size[0]:g}x{room.size[1]:g}x{room.height:g}_s{room.seed}_t{room.texel:g}_d{room.floor_decals:g}"
    key += "" if room.poster_text else "_nt"
    out = {}
    texs = None
    for name, _c, _u, _v, hu, hv in room.surfaces():
        path = folder / f"{key}_{name}.png"
        if not path.exists():
            texs = texs if texs is not None else room_textures(room)
            cv2.imwrite(str(path), texs[name])
        h, w = cv2.imread(str(path), cv2.IMREAD_UNCHANGED).shape[:2] if texs is None else texs[name].shape[:2]
        out[name] = (str(path.resolve()), (2 * hu / (w * room.texel), 2 * hv / (h * room.texel)))
    return out


def scene_spec(world: World, views: Mapping[str, str | os.PathLike], *, t: float = 0.0, texture_dir: str | os.PathLike,
               metal: Iterable[int] = (), samples: int = 16, seed: int = 0, bounces: int = 4,
               threads: int = 2, glare: Mapping[str, float] | None = None) -> dict[str, Any]:
    """The Blender spec of ``world`` at time ``t``, to render robot ``name``'s view into ``views[name]``.

    ``metal``: indices into ``world.props`` drawn as polished metal; the
    rest of the props are matte in their colour.  ``samples`` Cycles
    samples per pixel (adaptive, then denoised); ``seed`` Cycles' sampling
    seed.  Room textures go into ``texture_dir`` (reused when present).
    ``glare``: a lens's and sensor's glow around whatever is bright (the
    lit lights and their reflections), drawn by Blender's compositor after
    the render (its Glare node, Bloom): ``{"threshold": radiance above
    which light glows (1 = white), "size": the glow's reach (the node's
    Size, 0-1), "strength": its gain}``, by default 0.5 / 0.6 / 2 (about
    mutloc's own sensor bloom around a light 2-3 m away).  None: no glow
    (Cycles draws none).
    """
    glare_spec = None
    if glare is not None:
        try:
            glare_spec = {"threshold": 0.5, "size": 0.6, "strength": 2.0, **{k: float(v) for k, v in glare.items()}}
        except (TypeError, ValueError, AttributeError):
            raise InputError(f"glare must map threshold, size and strength to numbers, got {glare!r}") from None
        if set(glare_spec) != {"threshold", "size", "strength"} or not all(
                math.isfinite(v) and v > 0 for v in glare_spec.values()) or glare_spec["size"] > 1:
            raise InputError(f"glare must give a positive threshold, strength and a size in (0, 1], got {dict(glare)!r}")
    metal = {int(i) for i in metal}
    if any(not 0 <= i < len(world.props) for i in metal):
        raise InputError(f"metal props {sorted(metal)} out of range: the world has {len(world.props)} props")
    prims = scene_primitives(world, t)
    texs = _texture_files(world, Path(texture_dir))
    finish = "matte" if world.ball_finish is None else "plastic"
    props = [p for p in prims if p["marker"] == "#prop"]
    if len(props) != len(world.props):
        raise InputError("every prop must be one primitive")  # a guard on scene_primitives' layout
    prop_index = {id(p): i for i, p in enumerate(props)}
    objects: list[dict[str, Any]] = []
    for p in prims:
        kind = p["kind"]
        o: dict[str, Any] = {"kind": kind, "centre": p["centre"], "name": str(p["marker"] or p["robot"] or "room")}
        if kind == "sphere":
            o.update(radius=p["radius"], color=p["color"])
            if max(p["emission"]) > 0:
                o.update(finish="emissive", emission=p["emission"])
            elif p["marker"] and p["marker"] != "#prop":
                o["finish"] = finish
        elif kind == "quad":
            if "surface" in p:
                path, scale = texs[p["surface"]]
                o.update(texture=path, uv_scale=list(scale), color=p["color"])
            elif "tag" in p:
                # The printed card, one texel per cell, drawn with the nearest texel: sharp cell edges.
                o.update(texture=_tag_texture(p["tag"][0], int(p["tag"][1]), Path(texture_dir)), uv_scale=[1.0, 1.0],
                         color=p["color"], interpolation="Closest")
            else:
                o["color"] = p["color"]
            o.update(u=p["u"], v=p["v"], half_u=p["half_u"], half_v=p["half_v"])
        elif kind == "box":
            o.update(R=p["R"], half=p["half"], color=p["color"])
        else:
            if len({tuple(b) for b in p["bands"]}) > 1:
                raise InputError("banded cylinders are not drawn by the Blender renderer yet")
            o.update(axis=p["axis"], radius=p["radius"], half_length=p["half_length"], color=p["bands"][0])
        if p["marker"] == "#prop" and prop_index[id(p)] in metal:
            o["finish"] = "metal"
        objects.append(o)

    light = world.light
    lpos = world.light_position()
    centre = np.mean([world.pose(n, t).t for n in world.robots], axis=0)
    d = float(np.linalg.norm(lpos - centre))
    spec_light = {"position": [float(x) for x in lpos], "color": _lin_rgb(light.color),
                  "power_w": float(light.intensity * 4.0 * math.pi**2 * d * d),
                  "radius": _HARD_RADIUS if light.shadows else _SOFT_RADIUS}
    top = (world.room.height if world.room is not None else 2.6) - 0.02
    area = _FILL_SIZE[0] * _FILL_SIZE[1]
    fill = {"position": [float(centre[0]), float(centre[1]), float(top)], "size": list(_FILL_SIZE),
            "color": _lin_rgb(light.color), "power_w": float(_FILL_GAIN * light.ambient * math.pi * area)}

    spec_views = []
    for name, out in views.items():
        cam, T = _view_camera(world, name, t)
        spec_views.append({"robot": name, "size": [int(x) for x in cam.size], "K": np.asarray(cam.K).tolist(),
                           "lens": _lens_spec(cam, name), "R": T.R.tolist(), "t": T.t.tolist(),
                           "out": str(Path(out).resolve())})
    return {"render": {"samples": int(samples), "denoise": True, "seed": int(seed), "bounces": int(bounces),
                       "threads": int(threads), **({"glare": glare_spec} if glare_spec else {})},
            "background": _lin_rgb(world.background), "objects": objects, "light": spec_light, "fill": fill,
            "views": spec_views}


def _tag_texture(family: str, tag_id: int, folder: Path) -> str:
    """The printed tag (:func:`~mutloc.sim.world.tag_image`, one pixel per cell) as a PNG in ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"tag_{family}_{tag_id}.png"
    if not path.exists():
        cv2.imwrite(str(path), tag_image(family, tag_id))
    return str(path.resolve())


def _view_camera(world: World, key: str, t: float) -> tuple[Any, Pose]:
    """``(camera, camera -> world pose)`` of view ``key``: a robot with one camera, or ``ROBOT/CAMERA`` of a
    robot with several (its pose in the world is its body frame's; the camera's is ``pose @ mount.pose``)."""
    if CAMERA_SEPARATOR not in key:
        cam = world.camera(key)
        if cam is None:
            raise InputError(f"robot {key!r} has several cameras: name the view ROBOT/CAMERA")
        return cam, world.pose(key, t)
    robot, cname = key.split(CAMERA_SEPARATOR, 1)
    mounts = world.robot(robot).robot.mounts
    if cname not in mounts:
        raise InputError(f"robot {robot!r} has no camera {cname!r} (it has {sorted(mounts)})")
    mount = mounts[cname]
    return mount.camera, world.pose(robot, t) @ mount.pose


def _lens_spec(cam: Any, name: str) -> dict[str, Any]:
    """How Blender draws ``cam``: ``{"model": "pinhole"}`` (OpenCV ``K``, no distortion) or, for a fisheye
    of the ideal equidistant lens (Kannala-Brandt with k1..k4 = 0, ``r = f * theta``, square pixels, the
    principal point at the image centre), ``{"model": "fisheye", "f": f}``."""
    K = np.asarray(cam.K, float)
    dist = np.asarray(cam.dist, float)
    model = getattr(cam, "model", "pinhole")
    if model == "pinhole":
        if np.any(dist != 0):
            raise InputError(f"camera {name!r}: the Blender renderer draws pinhole cameras without distortion only "
                             "(dist must be zero)")
        return {"model": "pinhole"}
    if model != "fisheye":
        raise InputError(f"camera {name!r}: the Blender renderer draws pinhole and fisheye cameras, not {model!r}")
    W, H = (int(x) for x in cam.size)
    if (np.any(dist != 0) or abs(K[0, 0] - K[1, 1]) > 1e-9 * K[0, 0] or K[0, 1] != 0
            or abs(K[0, 2] - (W - 1) / 2) > 1e-9 or abs(K[1, 2] - (H - 1) / 2) > 1e-9):
        raise InputError(f"camera {name!r}: the Blender renderer draws the ideal equidistant fisheye only "
                         "(dist all zero, fx = fy, no skew, principal point at the image centre ((W-1)/2, (H-1)/2))")
    return {"model": "fisheye", "f": float(K[0, 0])}


def blender_python() -> str:
    """The interpreter that has ``bpy``: ``$MUTLOC_BLENDER_PYTHON``, else this one if it has it."""
    env = os.environ.get("MUTLOC_BLENDER_PYTHON")
    if env:
        if not Path(env).exists():
            raise MissingExtraError(f"MUTLOC_BLENDER_PYTHON={env} does not exist")
        return env
    if importlib.util.find_spec("bpy") is not None:
        return sys.executable
    raise MissingExtraError('rendering with Blender needs bpy, part of the render extra: pip install "mutloc[render]" '
                            "(in a virtual environment of its own; then set MUTLOC_BLENDER_PYTHON to its python)")


def render_spec(spec: Mapping[str, Any], *, python: str | None = None, timeout: float = 600.0
                ) -> dict[str, np.ndarray]:
    """Render ``spec`` (from :func:`scene_spec`) in Blender; ``{robot: uint8 BGR image}``, also written
    where the spec says."""
    py = python or blender_python()
    with tempfile.TemporaryDirectory() as tmp:
        f = Path(tmp) / "spec.json"
        f.write_text(json.dumps(spec))
        run = subprocess.run([py, str(BLENDER_SCRIPT), str(f)], capture_output=True, text=True, timeout=timeout)
    if run.returncode != 0:
        tail = " ".join((run.stderr or run.stdout).strip().splitlines()[-1:])
        raise InputError(f"Blender failed (exit {run.returncode}): {tail}")
    out = {}
    for v in spec["views"]:
        img = cv2.imread(v["out"], cv2.IMREAD_COLOR)
        if img is None:
            raise InputError(f"Blender wrote no image at {v['out']}")
        out[v["robot"]] = img
    return out


def ball_truth(world: World, observer: str, t: float = 0.0, *, samples: int = 64) -> dict[str, dict[str, float]]:
    """What ``observer``'s camera should report of every other robot's ball at ``t``.

    ``{marker: {"u", "v"}}``: the projection of the sphere's centre (SPEC
    pixels); ``radius_px``: the apparent radius (the outline's half angle
    over the pixel angle at the centre, ``f * tan(asin(r / D))``);
    ``distance_m``; ``hidden``: the share of the disc that other objects hide
    (rays over a ``samples`` x ``samples`` grid of the disc).
    """
    uvs = project_markers(world, observer, t)
    cam = world.camera(observer)
    T_cw = world.pose(observer, t).inverse()
    out: dict[str, dict[str, float]] = {}
    for rname, wr in world.robots.items():
        if rname == observer:
            continue
        for m in wr.robot.markers.values():
            if m.name not in uvs or m.kind != "ball":
                continue
            X = T_cw.apply(world.pose(rname, t).apply(m.position))
            D = float(np.linalg.norm(X))
            r = ball_radius(m)
            vis = ball_visibility(world, observer, m.name, t, samples=samples)
            out[m.name] = {"u": uvs[m.name][0], "v": uvs[m.name][1], "distance_m": D,
                           "radius_px": float(cam.K[0, 0] * math.tan(math.asin(min(1.0, r / D)))),
                           "hidden": float(1.0 - vis)}
    return out

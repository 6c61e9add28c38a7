"""Band geometry of banded-cylinder markers: band names, points on the axis,
and the rig with every band as a marker."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
from typing import Any

import numpy as np

from ...core.rig import Marker, Rig, Robot
from ...errors import RigError
from ...sim.world import cylinder_spec, cylinder_up  # the one validation of the rig key

__all__ = ["BAND_SEPARATOR", "band_marker_names", "band_points", "cylinder_spec", "expand_cylinder_bands"]

BAND_SEPARATOR = "#b"


def band_marker_names(name: str, n: int) -> list[str]:
    """``[NAME#b0, ..., NAME#b{n-1}]``."""
    return [f"{name}{BAND_SEPARATOR}{k}" for k in range(n)]


def band_points(marker: Marker, body: bool = False) -> tuple[list[str], np.ndarray]:
    """Names and 3-D positions (n, 3), robot frame, of the band centres on the axis.

    Same geometry as the renderer: band ``k`` of ``n`` spans the axis
    coordinate ``s`` (along :func:`~mutloc.sim.world.cylinder_up`: the robot's
    -y, or with ``body`` -- a robot with ``cameras`` -- its +z) in ``[h -
    2h(k+1)/n, h - 2hk/n]`` with ``h`` half the height, so its centre is at
    ``position + (h - 2h(k + 0.5)/n) * up`` (robot ``y = position_y - h +
    2h(k + 0.5)/n`` for a one-camera robot).
    """
    _, height, code = cylinder_spec(marker)
    n = len(code)
    s = 0.5 * height - height * (np.arange(n) + 0.5) / n
    pts = marker.position[None, :] + s[:, None] * cylinder_up(body)[None, :]
    return band_marker_names(marker.name, n), pts


def expand_cylinder_bands(rig: Rig | Mapping[str, Any] | str) -> Rig:
    """A copy of ``rig`` where each cylinder ``NAME`` also has band markers ``NAME#bK``.

    The bands are plain point markers (extra keys ``cylinder_of: NAME`` and
    ``band: K``); the cylinder marker itself is kept.  Idempotent.
    """
    from ...api import load_rig

    rig = load_rig(rig)
    robots: dict[str, Robot] = {}
    for rname, robot in rig.robots.items():
        new: dict[str, Marker] = dict(robot.markers)
        for name, marker in robot.markers.items():
            if marker.extra.get("cylinder_of") is not None or marker.extra.get("cylinder") is None:
                continue
            names, pts = band_points(marker, robot.is_body)
            for k, (bname, X) in enumerate(zip(names, pts)):
                if bname in new:
                    old = new[bname]
                    if old.extra.get("cylinder_of") == name and np.allclose(old.position, X, atol=1e-12):
                        continue
                    raise RigError(f"robot {rname!r}: marker {bname!r} exists, so cylinder {name!r}'s band "
                                   "markers cannot be added")
                new[bname] = Marker(name=bname, robot=rname, position=X, extra={"cylinder_of": name, "band": k})
        robots[rname] = replace(robot, markers=new)  # keeps the camera and base frame
    return Rig(robots)


# ---------------------------------------------------------------------------
# detection

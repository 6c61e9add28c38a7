"""The second look's ball refits through any lens: in a rectified view around each predicted ball.

:mod:`.second_look` measures a ball again where a pose puts it, its size fixed
(:func:`mutloc.detect.balls.refit.refit_ball`): rays cast from the predicted
centre, the rim fitted as a cone of the predicted angle.  That works in a
pinhole camera's own pixels.  Through a fisheye or omni lens the ball is
measured in a small pinhole view centred on its predicted direction
(:func:`mutloc.detect.views.view_towards`, as the tags' look does), the
result taken back to the raw image's pixels
(:func:`mutloc.detect.views.detection_to_raw`).

The first look's pixel figures of a ball seen through views (``radius_px``)
are in the pixels of the view it was found in (``info["view"]``); the
predicted size it is compared with is computed in that same view, so the
second look's size test means what it means for a pinhole camera.

:func:`context` makes the per-image object; :func:`refit` and
:func:`apparent_radius` take either kind.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..core.rig import Marker
from ..detect.base import Detection
from ..detect.views import View, detection_to_raw, needs_views, view_towards, views_for

__all__ = ["LensRefit", "context", "refit", "apparent_radius"]

#: Half field (degrees) of a refit view: this many times the ball's angular radius, within these bounds.
_VIEW_SCALE, _VIEW_HALF_FOV_DEG = 4.0, (6.0, 30.0)


class LensRefit:
    """One wide-angle camera's image and its refit contexts, one per view (cached for the frame)."""

    def __init__(self, image: np.ndarray, lens: Any) -> None:
        self.image = image
        self.lens = lens
        self._contexts: dict[int, Any] = {}

    def _context(self, view: View) -> Any:
        from ..detect.balls.refit import RefitContext

        key = id(view)
        if key not in self._contexts:
            self._contexts[key] = (view, RefitContext.of(view.rectify(self.image), view.camera))
        return self._contexts[key][1]

    def refit(self, name: str, marker: Marker, centre: np.ndarray, radius_offset_px: float = 0.0
              ) -> Detection | None:
        """``refit_ball`` in a view centred on camera-frame ``centre``, in raw pixels (None: not found)."""
        from ..detect.balls.refit import refit_ball
        from ..detect.balls.search import BallSearch

        X = np.asarray(centre, float)
        dist = float(np.linalg.norm(X))
        if not (math.isfinite(dist) and dist > 0.0):
            return None
        radius = BallSearch.from_marker(name, marker).radius_m
        ang = math.degrees(math.asin(min(1.0, radius / dist)))
        half = float(np.clip(_VIEW_SCALE * ang, *_VIEW_HALF_FOV_DEG))
        view = view_towards(self.lens, X, half_fov_deg=half)
        if view is None:
            return None
        found = refit_ball(self._context(view), name, marker, view.R.T @ X, radius_offset_px=radius_offset_px)
        return None if found is None else detection_to_raw(found, view)

    def apparent_radius(self, name: str, marker: Marker, centre: np.ndarray, first: Detection) -> float | None:
        """The radius (pixels) a ball at camera-frame ``centre`` has in the view ``first`` (a first-look
        detection) was found in: comparable with its ``radius_px``.  None without that view."""
        from ..detect.balls.refit import apparent_radius_px

        where = first.info.get("view") if first.info else None
        if not where:
            return None
        views = views_for(self.lens).views
        idx = int(where["index"])
        view = next((v for v in views if v.index == idx), None)
        if view is None:
            return None
        return apparent_radius_px(self._context(view), name, marker, view.R.T @ np.asarray(centre, float))


def context(image: np.ndarray, camera: Any) -> Any:
    """The refit context of one camera's image: the pinhole one (:class:`RefitContext`) or, through a wide
    lens, a :class:`LensRefit`."""
    if needs_views(camera):
        return LensRefit(image, camera)
    from ..detect.balls.refit import RefitContext

    return RefitContext.of(image, camera)


def refit(ctx: Any, name: str, marker: Marker, centre: np.ndarray, radius_offset_px: float = 0.0
          ) -> Detection | None:
    """:func:`~mutloc.detect.balls.refit.refit_ball` in the context's image, raw pixels, any lens."""
    if isinstance(ctx, LensRefit):
        return ctx.refit(name, marker, centre, radius_offset_px)
    from ..detect.balls.refit import refit_ball

    return refit_ball(ctx, name, marker, centre, radius_offset_px=radius_offset_px)


def apparent_radius(ctx: Any, name: str, marker: Marker, centre: np.ndarray, first: Detection) -> float | None:
    """The predicted radius in the pixels ``first``'s ``radius_px`` is in, any lens."""
    if isinstance(ctx, LensRefit):
        return ctx.apparent_radius(name, marker, centre, first)
    from ..detect.balls.refit import apparent_radius_px

    return apparent_radius_px(ctx, name, marker, centre)

"""Coloured-ball detector with sub-pixel, perspective-corrected centres.

A pipeline of stages, each a function over small dataclasses:

1. **Coarse search** (:mod:`.search`; half resolution by default, with a
   full-resolution pass for small balls of markers it did not find): HSV
   hue window around each marker's nominal colour (red wraps around
   0 deg); the saturation floor is a fraction of the marker's own
   saturation (shading scales RGB and leaves saturation alone) and the value
   floor follows the image's exposure, so shaded and dimly lit balls
   survive.  External contours of the mask are the candidate
   :class:`~.search.Blob` s; a RANSAC circle on each contour gives a first
   centre and radius that ignore straight occluding edges and ragged
   clutter.
2. **Sub-pixel rim** (:mod:`.rim`) at full resolution, only near the blob:
   along rays from the coarse centre the colour is unmixed into ball and
   background fractions, and each ray's rim radius is the integral of the
   ball fraction across a short window around the edge (a
   :class:`~.rim.Rim`).
3. **Fit** (:mod:`.fit`): with a :class:`~mutloc.core.camera.Camera` a
   circular cone of bearings whose axis is the direction of the sphere
   centre (perspective bias and lens distortion removed); without, an
   ellipse whose centre is reported.  A second round of rays from the
   fitted centre polishes the result (:func:`~.detector.refine_blob`).
4. **Choice** (:mod:`.choose`): each :class:`~.choose.Candidate` is scored;
   balls of one robot are chosen consistently with the rig, and markers
   take their best blobs greedily so two never share one.

Partly hidden balls (:mod:`.occlusion`): when much of a blob's rim is off
its coarse circle, the circle is found again from the visible outline at
full resolution (RANSAC whose inliers have radial normals), rim points on an
occluder's edge are dropped, and a ball with too little rim visible is
reported missing with the reason.  A robot's ball the rig check leaves
missing, beside one of its balls found whole, is looked for again where
the rig puts it (:mod:`.guided`): merged with clutter of its hue, or
hidden by more than half.  Real light (:mod:`.light`): a strong
colour cast is divided out before hues are compared and rims unmixed.

Every tuning value is a field of the frozen :class:`BallParams`.

Accuracy on exact supersampled renders of shaded balls (3 cm, 1-3 m,
f = 800 px, 960x540, textured background; ``tests/test_detect_balls.py``):
median error about 0.02 px clean and 0.1 px with noise, blur and JPEG.
Speed: over 100 frames/s of CPU time for four markers on one core
(``python bench/bench_detectors.py`` measures it).

Pixels follow the SPEC: ``(0, 0)`` is the centre of the top-left pixel.
"""

from .detector import detect_balls
from .params import DEFAULT_BALL_RADIUS_M, BallParams
from .search import BallSearch

__all__ = ["DEFAULT_BALL_RADIUS_M", "BallParams", "BallSearch", "detect_balls"]

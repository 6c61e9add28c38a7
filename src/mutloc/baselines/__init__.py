"""The methods the paper compares against, for the experiments.

- :mod:`.tag`: one-sided pose from a printed square tag (ARToolKit-like),
  OpenCV's detector and its square-marker PnP (``SOLVEPNP_IPPE_SQUARE``).
- :mod:`.egomotion`: feature matches between the two cameras' views of the
  shared scene, five-point essential matrix with RANSAC (Bundler-like); the
  scale is not observable and comes from an oracle.
- :mod:`.sfm`: structure from motion over every image (COLMAP through
  ``pycolmap``): the paper's Bundler baseline; metric scale from one known
  distance.
- :mod:`.dugas`: a closed form for two lights beside each camera, in the
  setting of Dugas, Giguere and Rekleitis (ISRR 2013).

They are not part of mutloc's solver; they exist so the paper's comparisons
can be rerun on the same rendered frames.
"""

from __future__ import annotations

__all__ = ["tag_pose", "egomotion_pose", "match_features", "dugas_pose", "SfmScene"]


def __getattr__(name: str):
    if name == "tag_pose":
        from .tag import tag_pose

        return tag_pose
    if name in ("egomotion_pose", "match_features"):
        from . import egomotion

        return getattr(egomotion, name)
    if name == "SfmScene":
        from .sfm import SfmScene

        return SfmScene
    if name == "dugas_pose":
        from .dugas import dugas_pose

        return dugas_pose
    raise AttributeError(name)

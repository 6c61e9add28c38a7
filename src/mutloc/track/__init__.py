"""Localization from images and streams."""

from .frames import FrameResult, detect_markers, localize_images, read_image

__all__ = ["FrameResult", "detect_markers", "localize_images", "read_image"]

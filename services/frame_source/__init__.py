"""Frames from a camera, video file, URL or image folder (``sources``); ``service``
publishes them on ``camera/frame``."""

from services.frame_source.sources import SourceEndedError, SourceLostError, open_source

__all__ = ["SourceEndedError", "SourceLostError", "open_source"]

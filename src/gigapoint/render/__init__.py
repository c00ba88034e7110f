"""The renderer: cameras, settings, the Backend contract, passes and their references, the facade."""

from .camera import VIEWS, Camera
from .frame import Frame, Image, RenderStats
from .renderer import render, render_frame
from .settings import RenderSettings, parse_color

__all__ = ["VIEWS", "Camera", "Frame", "Image", "RenderSettings", "RenderStats", "parse_color", "render", "render_frame"]

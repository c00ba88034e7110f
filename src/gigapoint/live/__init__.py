"""Live clouds: sensor streams drawn as they arrive, pose-tagged snapshots, recording and replay
(Kraft 2019's dynamic point clouds).

``LiveCloud`` (cloud.py) is the Renderable; depth.py turns depth images into points with
normals; sources.py reads streams (a synthetic sensor in the demo town, folders of frames, TUM
RGB-D sequences, ROS bags, recordings) and plays them into a LiveCloud; record.py records one.
"""

from .cloud import FrameInfo, LiveCloud, LiveStats
from .depth import depth_to_points, depth_to_points_reference

__all__ = ["FrameInfo", "LiveCloud", "LiveStats", "depth_to_points", "depth_to_points_reference"]

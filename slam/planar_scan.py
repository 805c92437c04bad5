"""A 3-D point cloud as the planar scan the mapper keyframes and describes places from.

`slam.pipeline.Mapper` maps point clouds (``--odometry kiss-icp``) with the planar
machinery: the cloud's odometry is 3-D, but keyframe selection, the place database and
the loop checks see `_planar_scan` of it.
"""

from __future__ import annotations

import numpy as np

from data.types import PointCloud, Scan


def _planar_scan(cloud: PointCloud) -> Scan:
    """A point cloud flattened into a 360-degree planar scan for keyframing and places.

    Points within 0.3 m of the sensor's height, binned by bearing (1 degree), nearest
    per bin; bins without points read as no return.
    """
    pts = cloud.points[np.abs(cloud.points[:, 2]) < 0.3]
    bins = 360
    angles = np.linspace(-np.pi, np.pi, bins, endpoint=False)
    ranges = np.full(bins, 100.0)
    if len(pts):
        r = np.hypot(pts[:, 0], pts[:, 1])
        b = ((np.arctan2(pts[:, 1], pts[:, 0]) + np.pi) / (2 * np.pi) * bins).astype(int) % bins
        np.minimum.at(ranges, b, r)
    return Scan(cloud.stamp, ranges, angles, 100.0, 0.0, None, cloud.index)

"""Stage 1, bags to posed scans: reading bags, decoding lidar messages, transforms.

``octofuse.scans`` depends only on numpy and rosbags (no ROS installation):

* :class:`BagSet` reads ROS 1 bags, ROS 2 bag folders (sqlite3 or MCAP) and
  bare ``.mcap``/``.db3`` files as one message stream in log time order;
* :func:`pointcloud2_to_xyz` and :func:`laserscan_to_xyz` turn sensor
  messages into numpy point arrays;
* :class:`TransformBuffer` interpolates tf trees and pose topics, and
  :func:`load_transforms` fills one from a :class:`BagSet`.
"""

from .bags import BagError, BagMessage, BagSet, TopicInfo
from .decode import POINTFIELD_DTYPES, laserscan_to_xyz, pointcloud2_to_xyz, stamp_to_ns
from .msgtypes import normalize_msgtype
from .se3 import invert_transform, matrix_to_quaternion, quaternion_to_matrix, transform_matrix
from .tf import (
    ConnectivityError,
    ExtrapolationError,
    TransformBuffer,
    TransformError,
    UnknownFrameError,
)
from .tf_bags import PoseSource, load_transforms

__all__ = [
    "POINTFIELD_DTYPES",
    "BagError",
    "BagMessage",
    "BagSet",
    "ConnectivityError",
    "ExtrapolationError",
    "PoseSource",
    "TopicInfo",
    "TransformBuffer",
    "TransformError",
    "UnknownFrameError",
    "invert_transform",
    "laserscan_to_xyz",
    "load_transforms",
    "matrix_to_quaternion",
    "normalize_msgtype",
    "pointcloud2_to_xyz",
    "quaternion_to_matrix",
    "stamp_to_ns",
    "transform_matrix",
]

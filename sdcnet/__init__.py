"""sdcnet: spacecraft depth completion from a gray image and a sparse LIDAR depth map.

The core package holds what every part shares and needs no torch: the camera model,
the metrics, point clouds. Subpackages map the repository's top-level folders:
``sdcnet.training`` (``training/``), ``sdcnet.evaluation``, ``sdcnet.export``, ``sdcnet.service``,
``sdcnet.client``.
"""

__version__ = "0.1.0"

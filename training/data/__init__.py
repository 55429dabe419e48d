"""Synthetic spacecraft dataset: procedural meshes, ray-cast camera and LIDAR, on-disk format."""

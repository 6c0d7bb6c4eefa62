"""From pixels to geometry: camera model, heightmaps (and, later, segmentation, pose and grasp detection)."""

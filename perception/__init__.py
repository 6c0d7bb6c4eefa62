"""From pixels to geometry: camera model, sensor noise, heightmaps, segmentation, block pose and tower detection,
and model-free grasp detection."""

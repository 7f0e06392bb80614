"""Sonar nodes: polar imager, highlight-extension point cloud, ICP localizer (seed 01)."""

"""gsslam.viz."""

"""gsslam.frontend."""

"""gsslam.bench."""

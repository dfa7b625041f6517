"""gsslam.io."""

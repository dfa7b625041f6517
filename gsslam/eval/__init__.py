"""gsslam.eval."""

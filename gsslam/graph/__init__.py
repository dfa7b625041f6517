"""gsslam.graph."""

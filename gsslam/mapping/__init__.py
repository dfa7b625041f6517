"""gsslam.mapping."""

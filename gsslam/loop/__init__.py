"""gsslam.loop."""

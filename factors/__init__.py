"""Custom GTSAM factors of gsslam: residuals with analytic Jacobians. Depends on gtsam and numpy only."""

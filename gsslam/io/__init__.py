"""File formats at the library's boundary: trajectories (TUM, KITTI), and later maps and checkpoints.

Readers return core types (:class:`gsslam.types.Trajectory` holds ``T_world_cam`` poses) and raise a
module-specific :class:`gsslam.errors.GsslamError` subclass that names the file and line on bad input.
Writers keep full precision: timestamps and translations read back bit-identical (float64), rotations
to ~1e-15.
"""

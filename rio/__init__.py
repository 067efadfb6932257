"""Radar-inertial odometry: point clouds, ego velocity, EKF, trajectory tools (pure computation)."""

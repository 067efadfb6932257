"""Simulation: raw ADC frames from the signal model, IMU, radar point clouds, the robot base's CAN frames,
targets and scenes (TOML, a few built in). Used by tests, benchmarks, the demo and the studies."""

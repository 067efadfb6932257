"""Recordings out to the formats other robotics tools read (MCAP for Foxglove)."""

"""Recordings of other tools turned into sarbot recordings: ROS bags (``bag``)."""

"""sarbot's files: the recording (schema v1), images, trajectories, and phase histories of other tools.

Every reader checks the schema on open and fails with a FileFormatError naming the file.
"""

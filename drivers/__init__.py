"""Device drivers (one process per device) and the hardware emulators used by replay."""

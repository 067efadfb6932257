"""The daemon side of sarbot: process supervision, ZeroMQ bus, HDF5 recorder, replay and the command line."""

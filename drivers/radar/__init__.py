"""Radar drivers: wire formats (a registry, SRF1 and DCA1000 in it), UDP reception, links and captures.

Adding a wire format: one module that defines ``WIRE_FORMAT = WireFormat(...)`` with a ``RadarStream``
(datagrams -> frames) and an encoder (frames -> datagrams), and one line in ``registry.BUILTIN``.
"""

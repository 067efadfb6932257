"""Devices the daemon brings up once its drivers listen and down before they stop (a TI radar's CLI and
its DCA1000), off the recorder's thread: a radar's configuration takes seconds, during which the IMU and
the other radars go on being recorded."""

from __future__ import annotations

import logging
import queue
import re
import threading
import time
from pathlib import Path

from imaging.core.errors import HardwareError, SarbotError

log = logging.getLogger(f"sarbot.{__name__}")


def udp_port_listening(port: int) -> bool | None:
    """Whether some socket of this machine is bound to UDP ``port`` (Linux /proc; None where it cannot tell)."""
    readable = False
    for table in (Path("/proc/net/udp"), Path("/proc/net/udp6")):
        try:
            lines = table.read_text().splitlines()[1:]
        except OSError:
            continue
        readable = True
        if any(int(line.split()[1].rsplit(":", 1)[1], 16) == port for line in lines if len(line.split()) > 1):
            return True
    return False if readable else None


def device_controls(links, given: dict[str, list[str]]) -> list:
    """The devices to bring up for ``links`` (``RadarLink``): ``given`` maps each device-control option
    (``--radar-cli``) to the values given, each for one radar (its name first: ``NAME=...`` or
    ``NAME,...``). The radar's wire format reads them (``WireFormat.control_options``) and says what to
    drive (``WireFormat.controls``); nothing here knows a format. SarbotError naming the option otherwise."""
    from drivers.radar import registry

    by_name = {link.name: link for link in links}
    settings: dict[str, dict] = {}
    for option, items in given.items():
        for item in items:
            name = re.split("[=,]", item, maxsplit=1)[0]
            link = by_name.get(name)
            if link is None or option not in link.format.control_options:
                formats = registry.taking_control_option(option)
                taking = [n for n, lk in by_name.items() if option in lk.format.control_options]
                raise SarbotError(f"{option} {name}: not a {' or '.join(formats)} radar of this recording (give it "
                                  f"with --radar {name}=PORT,format={formats[0] if formats else 'FORMAT'},..."
                                  f"{'; ' + ' or '.join(formats) + ' radars: ' + ', '.join(taking) if taking else ''})")
            try:
                settings.setdefault(name, {}).update(link.format.control_options[option](item))
            except ValueError as exc:
                raise SarbotError(f"{option} {item!r}: {exc}") from None
    return [control for name, values in settings.items() for control in by_name[name].format.controls(by_name[name], values)]


class DeviceBringUp:
    """Arms ``controls`` (objects with ``radar``, ``data_port`` and ``open() -> armed``, ``armed.arm() ->
    str``, ``armed.disarm() -> [problems]``) in a thread once each radar's driver listens; events for the
    recording go to ``events`` (drained by the daemon's loop); ``failed`` is set, and ``error`` holds why,
    when a device refuses."""

    def __init__(self, controls, listen_timeout_s: float = 30.0):
        self.controls = list(controls)
        self.listen_timeout_s = listen_timeout_s
        self.events: queue.Queue = queue.Queue()
        self.failed = threading.Event()
        self.error: Exception | None = None
        self.armed: list = []
        self._abort = threading.Event()
        self._thread = threading.Thread(target=self._run, name="devices", daemon=True)

    def start(self) -> "DeviceBringUp":
        if self.controls:
            self._thread.start()
        return self

    def _event(self, source: str, level: str, message: str) -> None:
        log.log({"info": logging.INFO, "warning": logging.WARNING}.get(level, logging.ERROR), "%s: %s", source, message)
        self.events.put((time.time_ns(), source, level, message))

    def _run(self) -> None:
        for control in self.controls:
            source = f"radar.{control.radar}"
            deadline = time.monotonic() + self.listen_timeout_s
            # The radar may only start once its driver listens, or its first frames are lost.
            while udp_port_listening(control.data_port) is False and time.monotonic() < deadline:
                if self._abort.wait(0.05):
                    return
            try:
                armed = control.open()
                self.armed.append(armed)
                self._event(source, "info", armed.arm())
            except (HardwareError, OSError) as exc:
                self.error = exc if isinstance(exc, HardwareError) else HardwareError(f"{source}: {exc}")
                self._event(source, "error", str(self.error))
                self.failed.set()
                return
            if self._abort.is_set():
                return

    def stop(self, record_event) -> None:
        """Wait for arming to end, then disarm in reverse order; ``record_event(t, source, level, msg)``
        takes the events left and what the shutdown reports."""
        self._abort.set()
        if self._thread.is_alive():
            self._thread.join(timeout=30)
        for armed in reversed(self.armed):
            for problem in armed.disarm():
                self._event(f"radar.{armed.control.radar}", "warning", f"on shutdown: {problem}")
        self.armed.clear()
        self.drain(record_event)

    def drain(self, record_event) -> None:
        while True:
            try:
                record_event(*self.events.get_nowait())
            except queue.Empty:
                return

"""Receive time stamps for a radar's UDP socket: the network card's (hardware, its PTP hardware clock) where
the card can stamp every datagram, else the kernel's (software, CLOCK_REALTIME). Linux only.

Linux stamps datagrams with ``SO_TIMESTAMPING``: each received datagram then carries a ``SCM_TIMESTAMPING``
control message of three timespecs -- [0] the kernel's software stamp (CLOCK_REALTIME), [1] a legacy
hardware stamp no driver fills any more, [2] the raw hardware stamp in the card's PTP hardware clock
(PHC, ``/dev/ptpN``). A card stamps received datagrams only when its receive filter is set
(``SIOCSHWTSTAMP``, needs CAP_NET_ADMIN); for a radar's UDP stream the filter must be ``all`` (``HWTSTAMP_FILTER_ALL``;
many cards stamp only PTP packets). What a card can do is asked with ``ETHTOOL_GET_TS_INFO`` (``SIOCETHTOOL``),
what ``ethtool -T IFACE`` prints.

A hardware stamp is on the PHC's time base, not the host's: where ptp4l disciplines the PHC from the radar's
grandmaster the PHC runs on the radar's PTP time, and hardware receive time minus frame end is the network
path alone (microseconds); without it the PHC runs free and that difference has no meaning. See
docs/architecture.md (receive time stamps) and docs/formats/recording.md (``receive_stamp``, ``nic_time_ns``).
"""

from __future__ import annotations

import ctypes
import dataclasses
import errno
import fcntl
import ipaddress
import socket
import struct

from imaging.core.errors import SarbotError

# include/uapi/asm-generic/socket.h (x86-64, arm64): SO_TIMESTAMPING_OLD, whose timespecs are 64-bit there.
SO_TIMESTAMPING = getattr(socket, "SO_TIMESTAMPING", 37)
SCM_TIMESTAMPING = SO_TIMESTAMPING

# include/uapi/linux/net_tstamp.h: enum of SOF_TIMESTAMPING_* flags (socket option and ethtool capabilities).
SOF_TIMESTAMPING_TX_HARDWARE = 1 << 0
SOF_TIMESTAMPING_TX_SOFTWARE = 1 << 1
SOF_TIMESTAMPING_RX_HARDWARE = 1 << 2
SOF_TIMESTAMPING_RX_SOFTWARE = 1 << 3
SOF_TIMESTAMPING_SOFTWARE = 1 << 4
SOF_TIMESTAMPING_SYS_HARDWARE = 1 << 5
SOF_TIMESTAMPING_RAW_HARDWARE = 1 << 6
# include/uapi/linux/net_tstamp.h: enum hwtstamp_tx_types, enum hwtstamp_rx_filters (first entries).
HWTSTAMP_TX_OFF = 0
HWTSTAMP_FILTER_NONE = 0
HWTSTAMP_FILTER_ALL = 1

# include/uapi/linux/sockios.h
SIOCGIFADDR = 0x8915
SIOCETHTOOL = 0x8946
SIOCSHWTSTAMP = 0x89B0
SIOCGHWTSTAMP = 0x89B1
# include/uapi/linux/ethtool.h
ETHTOOL_GET_TS_INFO = 0x00000041

#: The flags asked for software stamps: stamp on receive, and report the software stamp.
SOFTWARE_FLAGS = SOF_TIMESTAMPING_RX_SOFTWARE | SOF_TIMESTAMPING_SOFTWARE
#: For hardware stamps: the card's raw PHC stamp, and the software one beside it (the host's clock for
#: everything that measures against it, and the fallback of a datagram the card left unstamped).
HARDWARE_FLAGS = SOF_TIMESTAMPING_RX_HARDWARE | SOF_TIMESTAMPING_RAW_HARDWARE | SOFTWARE_FLAGS

# The names the kernel gives these bits (net/ethtool/common.c), which ethtool -T prints.
SOF_TIMESTAMPING_NAMES = ("hardware-transmit", "software-transmit", "hardware-receive", "software-receive",
                          "software-system-clock", "hardware-legacy-clock", "hardware-raw-clock", "option-id",
                          "sched-transmit", "ack-transmit", "option-cmsg", "option-tsonly", "option-stats",
                          "option-pktinfo", "option-tx-swhw", "bind-phc", "option-id-tcp")
TX_TYPE_NAMES = ("off", "on", "onestep-sync", "onestep-p2p")
RX_FILTER_NAMES = ("none", "all", "some", "ptpv1-l4-event", "ptpv1-l4-sync", "ptpv1-l4-delay-req",
                   "ptpv2-l4-event", "ptpv2-l4-sync", "ptpv2-l4-delay-req", "ptpv2-l2-event", "ptpv2-l2-sync",
                   "ptpv2-l2-delay-req", "ptpv2-event", "ptpv2-sync", "ptpv2-delay-req", "ntp-all")

#: The choices of ``--receive-stamps``.
MODES = ("auto", "hardware", "software")

_SCM_TIMESTAMPING = struct.Struct("qqqqqq")  # struct scm_timestamping: struct timespec ts[3], 64-bit time_t
_SCM_TIMESTAMPING_32 = struct.Struct("iiiiii")  # the same where time_t is 32 bits (SO_TIMESTAMPING_OLD on armhf)
_SOFTWARE_STAMP = struct.Struct("qq")  # its first timespec, ts[0]: the software stamp (64-bit time_t)
#: The smallest SCM_TIMESTAMPING payload: three 8-byte timespecs.
SCM_TIMESTAMPING_MIN_BYTES = _SCM_TIMESTAMPING_32.size
_TS_INFO = struct.Struct("IIiI3II3I")  # struct ethtool_ts_info
_HWTSTAMP_CONFIG = struct.Struct("iii")  # struct hwtstamp_config: flags, tx_type, rx_filter
_IFNAMSIZ = 16
_IFREQ_BYTES = 40  # struct ifreq on a 64-bit system: the name, then a 24-byte union


def parse_scm_timestamping(value: bytes) -> tuple[int, int, int]:
    """(software, legacy, raw hardware) stamps of a SCM_TIMESTAMPING control message, ns; 0 where empty."""
    s = (_SCM_TIMESTAMPING if len(value) >= _SCM_TIMESTAMPING.size else _SCM_TIMESTAMPING_32).unpack_from(value)
    return s[0] * 1_000_000_000 + s[1], s[2] * 1_000_000_000 + s[3], s[4] * 1_000_000_000 + s[5]


def software_stamp_ns(value: bytes) -> int:
    """The software stamp alone of a SCM_TIMESTAMPING control message, ns (0 where empty): what a datagram
    needs without hardware stamps, read per datagram (10,000 a second), so only its own timespec is unpacked
    where time_t is 64 bits; as ``parse_scm_timestamping(value)[0]``."""
    if len(value) >= _SCM_TIMESTAMPING.size:
        seconds, nanoseconds = _SOFTWARE_STAMP.unpack_from(value)
        return seconds * 1_000_000_000 + nanoseconds
    return parse_scm_timestamping(value)[0]


def _bit_names(mask: int, names: tuple[str, ...]) -> list[str]:
    return [names[i] if i < len(names) else f"bit{i}" for i in range(32) if mask >> i & 1]


@dataclasses.dataclass(frozen=True)
class TimestampingInfo:
    """What an interface can stamp (``ETHTOOL_GET_TS_INFO``)."""

    interface: str
    so_timestamping: int  # SOF_TIMESTAMPING_* the interface supports
    phc_index: int  # its PTP hardware clock /dev/ptpN; -1: none
    tx_types: int  # bit per HWTSTAMP_TX_*
    rx_filters: int  # bit per HWTSTAMP_FILTER_*

    @property
    def capabilities(self) -> list[str]:
        return _bit_names(self.so_timestamping, SOF_TIMESTAMPING_NAMES)

    @property
    def tx_modes(self) -> list[str]:
        return _bit_names(self.tx_types, TX_TYPE_NAMES)

    @property
    def rx_filter_modes(self) -> list[str]:
        return _bit_names(self.rx_filters, RX_FILTER_NAMES)

    def hardware_lacks(self) -> str | None:
        """What the interface lacks for a hardware stamp on every received datagram; None: nothing."""
        lacking = []
        if self.phc_index < 0:
            lacking.append("a PTP hardware clock")
        need = SOF_TIMESTAMPING_RX_HARDWARE | SOF_TIMESTAMPING_RAW_HARDWARE
        if self.so_timestamping & need != need:
            lacking.append("hardware receive stamps (hardware-receive, hardware-raw-clock)")
        if not self.rx_filters >> HWTSTAMP_FILTER_ALL & 1:
            lacking.append("the receive filter 'all' (it stamps "
                           + (", ".join(self.rx_filter_modes) or "nothing") + ")")
        return "; ".join(lacking) or None


def _ifreq(interface: str, data: ctypes.Array) -> bytearray:
    """A struct ifreq naming ``interface`` whose union holds a pointer to ``data``."""
    name = interface.encode()
    if len(name) >= _IFNAMSIZ:
        raise OSError(errno.EINVAL, f"{interface!r} is not an interface name")
    req = bytearray(_IFREQ_BYTES)
    struct.pack_into(f"{_IFNAMSIZ}sP", req, 0, name, ctypes.addressof(data))
    return req


def _ioctl_data(interface: str, request: int, data: ctypes.Array) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        fcntl.ioctl(sock.fileno(), request, _ifreq(interface, data))


def timestamping_info(interface: str) -> TimestampingInfo:
    """``ETHTOOL_GET_TS_INFO`` of ``interface``; OSError where the interface does not exist or does not say."""
    buf = ctypes.create_string_buffer(_TS_INFO.pack(ETHTOOL_GET_TS_INFO, 0, -1, 0, 0, 0, 0, 0, 0, 0, 0), _TS_INFO.size)
    _ioctl_data(interface, SIOCETHTOOL, buf)
    _, so_timestamping, phc_index, tx_types, *_, rx_filters, _, _, _ = _TS_INFO.unpack(buf.raw)
    return TimestampingInfo(interface, so_timestamping, phc_index, tx_types, rx_filters)


def hardware_rx_filter(interface: str) -> int | None:
    """The interface's hardware receive filter now (``SIOCGHWTSTAMP``); None where the driver does not say."""
    buf = ctypes.create_string_buffer(_HWTSTAMP_CONFIG.size)
    try:
        _ioctl_data(interface, SIOCGHWTSTAMP, buf)
    except OSError:
        return None
    return _HWTSTAMP_CONFIG.unpack(buf.raw)[2]


def enable_hardware_rx_filter(interface: str) -> None:
    """Make ``interface`` stamp every received packet (``SIOCSHWTSTAMP``, HWTSTAMP_FILTER_ALL), keeping its
    transmit stamping as it is; nothing where it does so already. SarbotError where it cannot (EPERM: the
    process lacks CAP_NET_ADMIN). The setting is the interface's and stays after the socket closes: ptp4l
    on the same card needs it too (``all`` includes PTP's packets)."""
    if hardware_rx_filter(interface) == HWTSTAMP_FILTER_ALL:
        return
    current = ctypes.create_string_buffer(_HWTSTAMP_CONFIG.size)
    tx_type = HWTSTAMP_TX_OFF
    try:
        _ioctl_data(interface, SIOCGHWTSTAMP, current)
        tx_type = _HWTSTAMP_CONFIG.unpack(current.raw)[1]
    except OSError:
        pass
    buf = ctypes.create_string_buffer(_HWTSTAMP_CONFIG.pack(0, tx_type, HWTSTAMP_FILTER_ALL), _HWTSTAMP_CONFIG.size)
    try:
        _ioctl_data(interface, SIOCSHWTSTAMP, buf)
    except PermissionError:
        raise SarbotError(f"{interface}: setting its hardware receive filter (SIOCSHWTSTAMP) needs CAP_NET_ADMIN "
                          "(run as root or give the capability), or set it beforehand: hwstamp_ctl -i "
                          f"{interface} -r 1") from None
    except OSError as exc:
        raise SarbotError(f"{interface}: its driver refused the hardware receive filter 'all' (SIOCSHWTSTAMP: "
                          f"{exc.strerror})") from None
    granted = _HWTSTAMP_CONFIG.unpack(buf.raw)[2]
    if granted != HWTSTAMP_FILTER_ALL:
        raise SarbotError(f"{interface}: asked to stamp every packet, its driver stamps "
                          f"{RX_FILTER_NAMES[granted] if granted < len(RX_FILTER_NAMES) else granted} instead")


def interface_addresses() -> dict[str, str]:
    """Interface name -> its (primary) IPv4 address (``SIOCGIFADDR``), for the interfaces that have one."""
    out = {}
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        for _, name in socket.if_nameindex():
            req = bytearray(_IFREQ_BYTES)
            struct.pack_into(f"{_IFNAMSIZ}s", req, 0, name.encode()[:_IFNAMSIZ - 1])
            try:
                fcntl.ioctl(sock.fileno(), SIOCGIFADDR, req)
            except OSError:
                continue  # no IPv4 address
            out[name] = socket.inet_ntoa(req[20:24])  # struct sockaddr_in: family, port, then the address
    return out


def interface_of(host: str, source: str | None = None) -> tuple[str | None, str]:
    """The interface a socket bound to ``host`` receives the radar's datagrams on, and how it was found (or
    why none was): the one holding ``host``; for a wildcard bind, the one the route to the radar's
    ``source`` address leaves by."""
    address = host
    if ipaddress.ip_address(host).is_unspecified:
        if source is None:
            return None, (f"bound to {host} (every interface) with no radar source address: hardware stamps need "
                          "the link's own address (HOST:PORT) or source=ADDRESS to tell the interface")
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
            try:
                probe.connect((source, 9))  # no packet is sent: the kernel only picks the route
            except OSError as exc:
                return None, f"no route to the radar's source {source} ({exc.strerror})"
            address = probe.getsockname()[0]
    if ipaddress.ip_address(address).is_loopback:
        return "lo", f"{address} is loopback"
    for name, ip in interface_addresses().items():
        if ip == address:
            how = f"holds {address}" if address == host else f"routes to the radar's source {source} (from {address})"
            return name, how
    return None, f"no interface holds {address} as its primary IPv4 address"


@dataclasses.dataclass(frozen=True)
class StampChoice:
    """Which receive stamps a radar's socket takes: ``source`` "hardware" or "software", the interface (None
    where unknown), its PTP hardware clock (/dev/ptpN, hardware only) and why this choice."""

    source: str
    interface: str | None
    phc: str | None
    reason: str

    def line(self) -> str:
        if self.source == "hardware":
            return f"receive stamps: hardware, {self.interface}'s PTP hardware clock {self.phc}"
        return f"receive stamps: software (CLOCK_REALTIME): {self.reason}"


def choose_receive_stamps(host: str, source: str | None = None, mode: str = "auto",
                          enable: bool = True) -> StampChoice:
    """Decide a socket's receive stamps. ``mode`` "software" takes the kernel's; "hardware" the card's, or a
    SarbotError naming the interface and what it lacks; "auto" the card's where it can, else the kernel's.
    With ``enable`` the card's receive filter is set to stamp every packet (``enable_hardware_rx_filter``);
    in "auto" a refusal (no CAP_NET_ADMIN) means software stamps, said in the reason."""
    if mode not in MODES:
        raise SarbotError(f"receive stamps {mode!r}: choose one of {', '.join(MODES)}")
    if mode == "software":
        return StampChoice("software", None, None, "chosen")
    interface, how = interface_of(host, source)
    reason = None
    info = None
    if interface is None:
        reason = how
    else:
        try:
            info = timestamping_info(interface)
        except OSError as exc:
            reason = f"{interface} does not say what it can stamp (ETHTOOL_GET_TS_INFO: {exc.strerror})"
        else:
            lacks = info.hardware_lacks()
            if lacks:
                reason = f"{interface} ({how}) lacks {lacks}"
    if reason is None and enable:
        try:
            enable_hardware_rx_filter(interface)
        except SarbotError as exc:
            reason = str(exc)
    if reason is None:
        return StampChoice("hardware", interface, f"/dev/ptp{info.phc_index}", how)
    if mode == "hardware":
        raise SarbotError(f"receive stamps hardware for {host}: {reason}")
    return StampChoice("software", interface, None, reason)


class CardFrameTimes:
    """Frame times on the network card's clock for a stream that has no time of its own (the DCA1000: a
    frame's time is the receipt of its first datagram, see drivers/radar/dca1000.py).

    With hardware stamps a frame's time is the card's stamp of that datagram: on the PHC, which ptp4l keeps
    on the radars' PTP time, and free of the host's interrupt and scheduling latency. Where the card left that
    datagram unstamped the frame's time is its host stamp moved by the card-minus-host difference of the latest
    datagram the card did stamp (the two clocks part by ppm: microseconds over the gap), so the series stays on
    the card's clock; ``estimated`` counts such frames. Before any stamped datagram the host stamp stays (and is
    counted as well)."""

    def __init__(self) -> None:
        self.card_minus_host_ns: int | None = None
        self.estimated = 0

    def observe(self, host_ns: int, nic_ns: int) -> None:
        """Take one datagram's two stamps (``nic_ns`` 0: the card left it unstamped)."""
        if nic_ns:
            self.card_minus_host_ns = int(nic_ns) - int(host_ns)

    def frame_time_ns(self, host_ns: int, nic_ns: int) -> int:
        """The frame's time from its first datagram's host stamp and card stamp (0: none)."""
        if nic_ns:
            return int(nic_ns)
        self.estimated += 1
        return int(host_ns) + (self.card_minus_host_ns or 0)

"""MAVLink links: real connections chosen by a pymavlink connection string, and an in-memory link.

Every link packs outbound messages with the companion's own identity and parses
inbound bytes with its own MAVLink 2 parser, so the real and in-memory links
behave the same: garbage and bad CRCs are logged and dropped, never raised.

(Over 400 lines: one job, getting bytes on and off a connection; the real and in-memory
links share the parser, the packing, the roles and the answering rule, and splitting them
would put those in a third module both import.)

Identity. The companion sits on the vehicle, so it uses the vehicle's system id
(1, PX4's default MAV_SYS_ID) and component id 191 (MAV_COMP_ID_ONBOARD_COMPUTER),
as MAVLink's microservice guide asks of companion computers. Both are
configurable. Messages that arrive from our own (system, component) are loops
of our own traffic and are dropped.

Connection strings (pymavlink's):

- ``udpin:0.0.0.0:14540`` (default): listen where PX4 SITL sends its offboard
  API stream; replies go to the address the last datagram came from. Until
  the vehicle has sent something, outbound packets go nowhere (UDP is silent).
- ``udpout:127.0.0.1:14580``: send to a fixed address.
- ``tcp:host:port``: connect (pymavlink retries; see ``tcp_retries``).
- a serial device, ``DEVICE`` or ``DEVICE,BAUD`` (pymavlink's form: ``/dev/ttyACM0``,
  ``/dev/ttyUSB0,921600``, ``COM3``); without a baud rate :data:`DEFAULT_BAUD` (57600).
  ``serial:DEVICE:BAUD`` is read the same way (:func:`serial_device`). A device path that
  does not exist is refused, naming it.

Time. A link never decides what time it is: it stamps each received message
with ``clock()`` at poll time (real links, default ``time.time``) or with the
time the harness passes to :meth:`MemoryLink.deliver` (lockstep).

Logging to a tlog records every packet sent and every valid packet received,
stamped ``t_s + tlog_offset_s`` (see :mod:`companion.mavlink.tlog`).

Roles. Each link has a ``name`` that every :class:`Received` carries: ``"autopilot"``
(the one link setpoints and commands go to) or ``"obstaclesN"`` (receive-only: sending
on it raises). On a ``udpin`` autopilot link the companion answers one address only:
the one the autopilot (:attr:`Link.peer`, set by the loop) last sent from, and none
before the autopilot is known (what would have gone is counted in
``stats.unaddressed``). pymavlink's own ``udpin`` writer
sends every packet to every address it has heard, which would hand setpoints to any
other system that talks to the port.
"""

from __future__ import annotations

import abc
import logging
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from pymavlink.dialects.v20 import common as mavlink2

from companion.mavlink.autopilots import DIALECT

from companion.mavlink.connection import DEFAULT_BAUD, NETWORK_PREFIXES as _NETWORK_PREFIXES, serial_device
from companion.mavlink.signing import enable_signing

from companion.errors import LinkError
from companion.mavlink.tlog import TlogWriter

logger = logging.getLogger(__name__)

DEFAULT_URL = "udpin:0.0.0.0:14540"
DEFAULT_SOURCE_SYSTEM = 1
MAV_COMP_ID_ONBOARD_COMPUTER = 191
DEFAULT_SOURCE_COMPONENT = MAV_COMP_ID_ONBOARD_COMPUTER
_MAX_READS_PER_POLL = 1000
_READ_SIZE = 65536


@dataclass(frozen=True)
class Received:
    """One valid inbound MAVLink message.

    Attributes
    ----------
    t_s : float
        Receive time from the link's clock (seconds; real links: since the
        Unix epoch; lockstep: simulated time).
    msg : pymavlink message
        The parsed message (``msg.get_srcSystem()`` etc.).
    raw : bytes
        The packet exactly as received (including a signature, if any).
    """

    t_s: float
    msg: mavlink2.MAVLink_message
    raw: bytes
    link: str = "autopilot"


@dataclass
class LinkStats:
    """Counters of a link since it was opened."""

    sent: int = 0
    received: int = 0
    bad: int = 0
    own_echo: int = 0
    signature_rejected: int = 0  # unsigned or badly signed packets dropped (signing on)
    bytes_in: int = 0
    bytes_out: int = 0
    unaddressed: int = 0  # packets not sent: the peer's address is not known yet


class Link(abc.ABC):
    """Base of every link: pack and send, parse and poll, optional tlog.

    Parameters
    ----------
    clock : callable () -> float
        Time source in seconds for send stamps (and receive stamps of real links).
    source_system, source_component : int
        The companion's MAVLink identity (default 1 and 191).
    tlog : TlogWriter, path or None
        Record every packet sent and received. A path opens a writer the link
        owns (closed by :meth:`close`); a writer stays the caller's to close.
    tlog_offset_s : float
        Added to link times for the tlog, whose stamps are seconds since the
        Unix epoch (0 for real links on ``time.time``).
    signing_key : bytes, optional
        32-byte MAVLink 2 signing key: outbound packets are signed and inbound
        unsigned packets dropped unless ``accept_unsigned``.
    name : str
        The link's role, carried by every :class:`Received`: ``"autopilot"`` or ``"obstaclesN"``.
    receive_only : bool
        Refuse to send (obstacle links).
    """

    def __init__(
        self,
        *,
        clock: Callable[[], float],
        source_system: int = DEFAULT_SOURCE_SYSTEM,
        source_component: int = DEFAULT_SOURCE_COMPONENT,
        tlog: TlogWriter | str | os.PathLike | None = None,
        tlog_offset_s: float = 0.0,
        signing_key: bytes | None = None,
        signing_link_id: int = 0,
        accept_unsigned: bool = False,
        name: str = "autopilot",
        receive_only: bool = False,
    ) -> None:
        if not (1 <= int(source_system) <= 255 and 0 <= int(source_component) <= 255):
            raise LinkError(f"MAVLink source ids out of range: system {source_system}, component {source_component}")
        self.clock = clock
        self.source_system = int(source_system)
        self.source_component = int(source_component)
        self._mav = DIALECT.MAVLink(None, self.source_system, self.source_component)
        self._mav.robust_parsing = True
        self.stats = LinkStats()
        self._owns_tlog = tlog is not None and not isinstance(tlog, TlogWriter)
        self.tlog: TlogWriter | None = TlogWriter(tlog) if self._owns_tlog else tlog  # type: ignore[arg-type]
        self.tlog_offset_s = float(tlog_offset_s)
        self._closed = False
        self.name = str(name)
        self.receive_only = bool(receive_only)
        #: (system, component) the link's outbound traffic is for (the autopilot), set by the loop.
        self.peer: tuple[int, int] | None = None
        if signing_key is not None:
            self._setup_signing(bytes(signing_key), int(signing_link_id), bool(accept_unsigned))

    # ------------------------------------------------------------------ identity and signing

    @property
    def key(self) -> tuple[int, int]:
        """The companion's own (system id, component id)."""
        return (self.source_system, self.source_component)

    def set_source(self, system: int, component: int) -> None:
        """Send as (``system``, ``component``) from now on (the fleet link speaks for the vehicle,
        whose system id is known only once its HEARTBEAT is heard); signing, if on, is kept."""
        if not (1 <= int(system) <= 255 and 0 <= int(component) <= 255):
            raise LinkError(f"MAVLink source ids out of range: system {system}, component {component}")
        self.source_system, self.source_component = int(system), int(component)
        self._mav.srcSystem, self._mav.srcComponent = self.source_system, self.source_component

    @property
    def listens_only(self) -> bool:
        """Whether the link cannot send to everyone it hears (a ``udpin`` server answers one peer):
        a fleet link of this kind is for listening; the announcements go out on the others."""
        return False

    def _setup_signing(self, key: bytes, link_id: int, accept_unsigned: bool) -> None:
        if len(key) != 32:
            raise LinkError(f"MAVLink 2 signing key must be 32 bytes, got {len(key)}")
        enable_signing(self._mav, key, link_id=link_id, now_s=self.clock() + self.tlog_offset_s)
        if accept_unsigned:
            self._mav.signing.allow_unsigned_callback = lambda _mav, _msgid: True

    # ------------------------------------------------------------------ sending

    def send(self, msg: mavlink2.MAVLink_message, t_s: float | None = None) -> bytes:
        """Pack ``msg`` with our identity and the next sequence number, send it, log it.

        Parameters
        ----------
        msg : the message.
        t_s : the time the message belongs to (the control loop's tick), stamped in the
            tlog so a replay ticks at exactly the same times; default: the link's clock now.

        Returns
        -------
        bytes
            The packet as sent.

        Raises
        ------
        LinkError
            If the link is closed or the transport fails.
        """
        if self._closed:
            raise LinkError(f"{self!r} is closed")
        if self.receive_only:
            raise LinkError(f"{self!r} is receive-only (link {self.name!r}); not sending {msg.get_type()}")
        packet = bytes(msg.pack(self._mav))
        self._mav.seq = (self._mav.seq + 1) % 256
        t_s = self.clock() if t_s is None else float(t_s)
        self._write(packet)
        self.stats.sent += 1
        self.stats.bytes_out += len(packet)
        if self.tlog is not None:
            self.tlog.write(t_s + self.tlog_offset_s, packet)
        return packet

    @abc.abstractmethod
    def _write(self, packet: bytes) -> None:
        """Hand one packet to the transport."""

    # ------------------------------------------------------------------ receiving

    def _parse(self, t_s: float, chunk: bytes, *, datagram: bool = False) -> list[Received]:
        """Feed bytes to our parser; return the valid messages completed by them.

        With ``datagram`` (UDP), the chunk is a whole datagram: a partial packet
        left at its end cannot be completed by the next datagram and is dropped,
        so it cannot swallow the next packet.
        """
        self.stats.bytes_in += len(chunk)
        out: list[Received] = []
        try:
            msgs = self._mav.parse_buffer(chunk) or []
        except Exception as exc:  # pymavlink should not raise with robust_parsing; never let it through
            logger.warning("MAVLink parser error, %d bytes dropped: %s", len(chunk), exc)
            self._reset_parser()
            self.stats.bad += 1
            return out
        for msg in msgs:
            if msg.get_type() == "BAD_DATA":
                self.stats.bad += 1
                if "signature" in str(msg.reason):
                    self.stats.signature_rejected += 1
                    if self.stats.signature_rejected & (self.stats.signature_rejected - 1) == 0:  # 1, 2, 4, 8...
                        logger.warning("rejected %d unsigned or badly signed packets", self.stats.signature_rejected)
                logger.debug("dropped bad MAVLink data (%s): %s", msg.reason, bytes(msg.data)[:32].hex())
                continue
            if (msg.get_srcSystem(), msg.get_srcComponent()) == self.key:
                self.stats.own_echo += 1
                continue
            raw = bytes(msg.get_msgbuf())
            self.stats.received += 1
            if self.tlog is not None:
                self.tlog.write(t_s + self.tlog_offset_s, raw)
            out.append(Received(t_s, msg, raw, self.name))
        if datagram and self._mav.buf_len() > 0:
            logger.debug("dropped %d bytes of a partial packet at the end of a datagram", self._mav.buf_len())
            self._reset_parser()
            self.stats.bad += 1
        return out

    def _reset_parser(self) -> None:
        self._mav.buf = bytearray()
        self._mav.buf_index = 0
        self._mav.expected_length = mavlink2.HEADER_LEN_V1 + 2

    @abc.abstractmethod
    def poll(self) -> list[Received]:
        """Every valid message that arrived since the last poll, in arrival order. Never blocks."""

    def fileno(self) -> int | None:
        """The file descriptor that turns readable when bytes arrive (a socket, a serial device),
        or None (no descriptor: an in-memory link). The stream waits on it between polls."""
        return None

    # ------------------------------------------------------------------ closing

    def close(self) -> None:
        """Close the transport and a tlog the link owns. Idempotent."""
        if self._closed:
            return
        self._closed = True
        try:
            self._close_transport()
        finally:
            if self.tlog is not None:
                if self._owns_tlog:
                    self.tlog.close()
                else:
                    self.tlog.flush()

    def _close_transport(self) -> None:
        """Release transport resources (override)."""

    @property
    def closed(self) -> bool:
        return self._closed

    def __enter__(self) -> "Link":
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()


class MemoryLink(Link):
    """In-memory link for lockstep runs: the harness moves the bytes and supplies the time.

    Parameters
    ----------
    clock : callable () -> float
        Simulated time in seconds, used to stamp sent packets in the tlog.
    tlog_offset_s : float
        Added to simulated time in tlog stamps; the lockstep harness passes mavsim's
        lockstep epoch, so a lockstep tlog has plausible, reproducible epoch stamps.
    **kwargs
        As :class:`Link`.

    Examples
    --------
    >>> link = MemoryLink(clock=lambda: sim.time_s)              # doctest: +SKIP
    >>> for t, pkt in sim.advance(0.05): link.deliver(t, pkt)    # doctest: +SKIP
    >>> for pkt in link.take_outbound(): sim.write(pkt)          # doctest: +SKIP
    """

    def __init__(self, *, clock: Callable[[], float], tlog_offset_s: float = 0.0, **kwargs) -> None:
        super().__init__(clock=clock, tlog_offset_s=tlog_offset_s, **kwargs)
        self._inbox: list[tuple[float, bytes]] = []
        self._outbox: list[bytes] = []

    def deliver(self, t_s: float, packet: bytes) -> None:
        """Harness to companion: bytes that arrived at simulated time ``t_s`` (any chunking)."""
        if self._closed:
            raise LinkError("MemoryLink is closed")
        self._inbox.append((float(t_s), bytes(packet)))

    def take_outbound(self) -> list[bytes]:
        """Companion to harness: packets sent since the last call, in send order."""
        out, self._outbox = self._outbox, []
        return out

    def _write(self, packet: bytes) -> None:
        self._outbox.append(packet)

    def poll(self) -> list[Received]:
        inbox, self._inbox = self._inbox, []
        out: list[Received] = []
        for t_s, chunk in inbox:
            out.extend(self._parse(t_s, chunk))
        return out

    def __repr__(self) -> str:
        return f"MemoryLink(source={self.key})"


class MavutilLink(Link):
    """A real connection opened by ``pymavlink.mavutil.mavlink_connection``.

    Only the transport of pymavlink is used (``recv``/``write`` of raw bytes);
    parsing and packing are the link's own, as for :class:`MemoryLink`.

    Parameters
    ----------
    url : str
        pymavlink connection string (see the module docstring); default
        ``udpin:0.0.0.0:14540``. Log files are refused: replay reads them with
        :func:`companion.mavlink.tlog.read_tlog`.
    clock : callable () -> float
        Receive and send stamps, default ``time.time``.
    baud : int
        Serial baud rate when ``url`` gives none (``DEVICE,BAUD`` gives one).
    tcp_retries : int
        Connection attempts for ``tcp:`` (one second apart, pymavlink's way).
    **kwargs
        As :class:`Link`.

    Raises
    ------
    LinkError
        If the connection cannot be opened (the message names the URL).
    """

    def __init__(
        self,
        url: str = DEFAULT_URL,
        *,
        clock: Callable[[], float] = time.time,
        baud: int = DEFAULT_BAUD,
        tcp_retries: int = 3,
        **kwargs,
    ) -> None:
        super().__init__(clock=clock, **kwargs)
        self.url = url
        target = url
        try:
            if not url.startswith(_NETWORK_PREFIXES) and Path(url).is_file():
                raise LinkError(f"{url!r} is a file, not a connection; replay logs with companion.mavlink.tlog.read_tlog")
            serial = serial_device(url)
            if serial is not None:
                target, baud = serial
                if Path(target).is_file():
                    raise LinkError(f"{target!r} is a file, not a serial device")
        except LinkError:
            if self.tlog is not None and self._owns_tlog:
                self.tlog.close()
            raise
        from pymavlink import mavutil

        try:
            self._conn = mavutil.mavlink_connection(
                target,
                baud=baud,
                source_system=self.source_system,
                source_component=self.source_component,
                retries=tcp_retries,
                autoreconnect=False,
            )
        except Exception as exc:  # socket.error, serial.SerialException, ValueError from pymavlink
            if self.tlog is not None and self._owns_tlog:
                self.tlog.close()
            raise LinkError(f"cannot open MAVLink connection {url!r}: {exc}") from exc
        self._datagram = url.startswith(("udpin:", "udpout:", "udp:", "udpbcast:"))
        # udpin (server): one reply address, chosen here, instead of pymavlink's send-to-all.
        self._server = url.startswith(("udpin:", "udp:")) and getattr(self._conn, "udp_server", False)
        self._address_of: dict[tuple[int, int], tuple] = {}
        logger.info("opened MAVLink connection %s as system %d component %d", url, *self.key)

    @property
    def listens_only(self) -> bool:
        return self._server

    def fileno(self) -> int | None:
        fd = getattr(self._conn, "fd", None)   # pymavlink's udp, tcp and serial connections keep it
        return fd if isinstance(fd, int) and fd >= 0 else None

    def destination(self) -> tuple | None:
        """Where a udpin link sends: the peer's last address; None (nothing is sent, it is
        counted as unaddressed) while the peer is unknown or not heard on this link. Before
        the loop knows its autopilot it answers nobody: the first sender heard may be an
        obstacle source, and the autopilot streams to the companion unasked."""
        if self.peer is None:
            return None
        return self._address_of.get(self.peer)

    def _write(self, packet: bytes) -> None:
        try:
            if self._server:
                address = self.destination()
                if address is None:
                    self.stats.unaddressed += 1
                    return
                self._conn.port.sendto(packet, address)
            else:
                self._conn.write(packet)
        except OSError as exc:
            raise LinkError(f"write to {self.url!r} failed: {exc}") from exc

    def poll(self) -> list[Received]:
        if self._closed:
            raise LinkError(f"{self!r} is closed")
        out: list[Received] = []
        for _ in range(_MAX_READS_PER_POLL):
            if self._server:
                got = self._recv_from()
                if got is None:
                    break
                chunk, address = got
                received = self._parse(self.clock(), chunk, datagram=True)
                for rx in received:
                    key = (rx.msg.get_srcSystem(), rx.msg.get_srcComponent())
                    if key in self._address_of or len(self._address_of) < 256:
                        self._address_of[key] = address
                out.extend(received)
                continue
            try:
                chunk = self._conn.recv(_READ_SIZE)
            except OSError as exc:
                raise LinkError(f"read from {self.url!r} failed: {exc}") from exc
            if not chunk:
                break
            if isinstance(chunk, str):  # pymavlink returns "" or str on some paths
                chunk = chunk.encode("latin-1")
            out.extend(self._parse(self.clock(), bytes(chunk), datagram=self._datagram))
        return out

    def _recv_from(self) -> tuple[bytes, tuple] | None:
        """One datagram and its source address from a udpin socket, or None if none is waiting."""
        try:
            data, address = self._conn.port.recvfrom(_READ_SIZE)
        except (BlockingIOError, InterruptedError):
            return None
        except ConnectionRefusedError:  # ICMP port unreachable of an earlier send (Linux)
            return None
        except OSError as exc:
            raise LinkError(f"read from {self.url!r} failed: {exc}") from exc
        return bytes(data), address

    def _close_transport(self) -> None:
        self._conn.close()

    def __repr__(self) -> str:
        return f"MavutilLink({self.url!r}, name={self.name!r}, source={self.key})"


def open_link(url: str = DEFAULT_URL, **kwargs) -> MavutilLink:
    """Open a real link from a pymavlink connection string; see :class:`MavutilLink`."""
    return MavutilLink(url, **kwargs)

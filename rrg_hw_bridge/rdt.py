"""ATI Net F/T Raw Data Transfer (RDT) over UDP: request and record codecs, the counts ↔ SI
calibration, and a threaded client that streams one box's wrenches.

The protocol (rrg_hw_bridge.config, RDT section): the host sends an 8-byte request ``>HHI``
(header 0x1234, command, sample count with 0 = forever) to the box's UDP port 49152; the box
answers START_REALTIME with one 36-byte record ``>III6i`` per sample (rdt_sequence, ft_sequence,
status, Fx Fy Fz Tx Ty Tz in counts) sent to the requester's address and port. rdt_sequence
counts the records of one stream (a jump is a lost datagram); a non-zero status word is an error.
"""

from __future__ import annotations

import logging
import socket
import struct
import threading
import time
import urllib.request
import xml.etree.ElementTree as ET
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from .config import (
    RDT_CMD_RESET_THRESHOLD_LATCH,
    RDT_CMD_SET_SOFTWARE_BIAS,
    RDT_CMD_START_BUFFERED,
    RDT_CMD_START_REALTIME,
    RDT_CMD_STOP,
    RDT_DEFAULT_COUNTS_PER_FORCE,
    RDT_DEFAULT_COUNTS_PER_TORQUE,
    RDT_HEADER,
    RDT_PORT,
    RDT_RATE_WINDOW,
    RDT_RECEIVE_BUFFER,
    RDT_RECORD_FORMAT,
    RDT_REQUEST_FORMAT,
    RDT_SOCKET_TIMEOUT,
)

__all__ = [
    "COMMANDS",
    "DEFAULT_COUNTS_PER_FORCE",
    "DEFAULT_COUNTS_PER_TORQUE",
    "RDT_CMD_RESET_THRESHOLD_LATCH",
    "RDT_CMD_SET_SOFTWARE_BIAS",
    "RDT_CMD_START_BUFFERED",
    "RDT_CMD_START_REALTIME",
    "RDT_CMD_STOP",
    "RDT_HEADER",
    "RDT_PORT",
    "RECORD_SIZE",
    "REQUEST_SIZE",
    "BoxConfig",
    "Calibration",
    "RdtClient",
    "RdtHealth",
    "RdtProtocolError",
    "RdtRecord",
    "RdtSample",
    "decode_record",
    "decode_request",
    "encode_record",
    "encode_request",
    "box_config_xml",
    "parse_box_config",
    "read_box_config",
]

log = logging.getLogger(__name__)

DEFAULT_COUNTS_PER_FORCE = RDT_DEFAULT_COUNTS_PER_FORCE
DEFAULT_COUNTS_PER_TORQUE = RDT_DEFAULT_COUNTS_PER_TORQUE

#: Every RDT command by name.
COMMANDS = {
    "STOP": RDT_CMD_STOP,
    "START_REALTIME": RDT_CMD_START_REALTIME,
    "START_BUFFERED": RDT_CMD_START_BUFFERED,
    "RESET_THRESHOLD_LATCH": RDT_CMD_RESET_THRESHOLD_LATCH,
    "SET_SOFTWARE_BIAS": RDT_CMD_SET_SOFTWARE_BIAS,
}

_REQUEST = struct.Struct(RDT_REQUEST_FORMAT)
_RECORD = struct.Struct(RDT_RECORD_FORMAT)
_RECORD_HEAD = struct.Struct(RDT_RECORD_FORMAT[:4])  # ">III": the three sequence/status words
#: Byte offset and numpy dtype of the six big-endian int32 counts inside a record.
_COUNTS_OFFSET = _RECORD_HEAD.size
_COUNTS_DTYPE = np.dtype(">i4")
REQUEST_SIZE = _REQUEST.size  # 8
RECORD_SIZE = _RECORD.size  # 36
_U32 = 0xFFFF_FFFF
_I32_MIN, _I32_MAX = -(2**31), 2**31 - 1


class RdtProtocolError(ValueError):
    """A byte string is not a valid RDT request or record."""


# ------------------------------------------------------------------------ codecs
def encode_request(command: int, sample_count: int = 0) -> bytes:
    """The 8-byte RDT request for ``command`` and ``sample_count`` records (0 = forever)."""
    if not 0 <= command <= 0xFFFF:
        raise RdtProtocolError(f"RDT command {command!r} is not a uint16")
    if not 0 <= sample_count <= _U32:
        raise RdtProtocolError(f"RDT sample count {sample_count!r} is not a uint32")
    return _REQUEST.pack(RDT_HEADER, command, sample_count)


def decode_request(data: bytes) -> tuple[int, int]:
    """(command, sample_count) of an 8-byte RDT request; refuses any other length or header."""
    if len(data) != REQUEST_SIZE:
        raise RdtProtocolError(f"RDT request is {len(data)} bytes, expected {REQUEST_SIZE}")
    header, command, count = _REQUEST.unpack(data)
    if header != RDT_HEADER:
        raise RdtProtocolError(f"RDT request header 0x{header:04x}, expected 0x{RDT_HEADER:04x}")
    return command, count


@dataclass(frozen=True)
class RdtRecord:
    """One RDT record: sequence numbers, status word and the six readings [counts]."""

    rdt_sequence: int
    ft_sequence: int
    status: int
    counts: tuple[int, int, int, int, int, int]


def encode_record(rec: RdtRecord) -> bytes:
    """The 36-byte RDT datagram of ``rec``."""
    if len(rec.counts) != 6:
        raise RdtProtocolError(f"an RDT record has 6 counts, got {len(rec.counts)}")
    try:
        return _RECORD.pack(rec.rdt_sequence, rec.ft_sequence, rec.status, *rec.counts)
    except struct.error as e:
        raise RdtProtocolError(f"RDT record out of range: {e}") from e


def decode_record(data: bytes) -> RdtRecord:
    """The record in a 36-byte RDT datagram; refuses any other length."""
    if len(data) != RECORD_SIZE:
        raise RdtProtocolError(
            f"RDT record is {len(data)} bytes, expected {RECORD_SIZE} (>III6i); "
            "buffered mode (several records per datagram) is not supported"
        )
    seq, ft, status, *counts = _RECORD.unpack(data)
    return RdtRecord(seq, ft, status, tuple(counts))


# ------------------------------------------------------------------------ calibration
@dataclass(frozen=True)
class Calibration:
    """Counts per N and per N m of one box (its netftapi2.xml cfgcpf / cfgcpt)."""

    counts_per_force: float = DEFAULT_COUNTS_PER_FORCE
    counts_per_torque: float = DEFAULT_COUNTS_PER_TORQUE

    def __post_init__(self) -> None:
        if not (self.counts_per_force > 0 and self.counts_per_torque > 0):
            raise ValueError(f"counts per unit must be positive: {self}")

    @property
    def scale(self) -> np.ndarray:
        """(6,) SI units per count: [N, N, N, N m, N m, N m] / count."""
        f, t = 1.0 / self.counts_per_force, 1.0 / self.counts_per_torque
        return np.array([f, f, f, t, t, t])

    def wrench(self, counts: Sequence[int] | np.ndarray) -> np.ndarray:
        """(6,) wrench [N, N m] of six readings [counts]."""
        return np.asarray(counts, dtype=float) * self.scale

    def counts(self, wrench: Sequence[float] | np.ndarray) -> tuple[int, ...]:
        """Six readings [counts] of a wrench (6,) [N, N m], rounded to the nearest count and
        saturated at the record field's int32 range."""
        per = np.array([self.counts_per_force] * 3 + [self.counts_per_torque] * 3)
        c = np.clip(np.rint(np.asarray(wrench, dtype=float) * per), _I32_MIN, _I32_MAX)
        return tuple(int(x) for x in c)


# ------------------------------------------------------------------------ box configuration
#: The box's configuration page: its active configuration's counts per force and torque unit
#: (cfgcpf, cfgcpt), those units (scfgfu, scfgtu) and the RDT output rate (comrdtrate).
CONFIG_PAGE = "netftapi2.xml"
#: Force and torque units a box may be set to (scfgfu / scfgtu, as ATI's Net F/T manual lists
#: them), in N and N m; a box in any other unit is refused.
FORCE_UNITS = {
    "N": 1.0,
    "kN": 1e3,
    "lbf": 4.4482216152605,
    "klbf": 4448.2216152605,
    "kgf": 9.80665,
    "gf": 9.80665e-3,
}
TORQUE_UNITS = {
    "N-m": 1.0,
    "N-mm": 1e-3,
    "kN-m": 1e3,
    "lbf-in": 0.1129848290276167,
    "lbf-ft": 1.3558179483314004,
    "kgf-cm": 0.0980665,
    "gf-cm": 9.80665e-5,
}


@dataclass(frozen=True)
class BoxConfig:
    """A box's active configuration (its netftapi2.xml): the calibration in SI units, the RDT
    output rate [Hz] and the units the box is set to."""

    calibration: Calibration
    rdt_rate_hz: float
    force_unit: str
    torque_unit: str

    def describe(self) -> str:
        c = self.calibration
        return (
            f"{c.counts_per_force:g} counts/N, {c.counts_per_torque:g} counts/(N m) (box in "
            f"{self.force_unit}, {self.torque_unit}), RDT at {self.rdt_rate_hz:g} Hz"
        )


def parse_box_config(page: bytes | str) -> BoxConfig:
    """The BoxConfig of a netftapi2.xml page; ValueError when a field is missing or a unit
    unknown."""
    root = ET.fromstring(page)
    fields = {el.tag.rsplit("}", 1)[-1].lower(): (el.text or "").strip() for el in root.iter()}
    missing = [k for k in ("cfgcpf", "cfgcpt", "scfgfu", "scfgtu", "comrdtrate") if k not in fields]
    if missing:
        raise ValueError(f"{CONFIG_PAGE} lacks {', '.join(missing)}")
    force_unit, torque_unit = fields["scfgfu"], fields["scfgtu"]
    if force_unit not in FORCE_UNITS or torque_unit not in TORQUE_UNITS:
        raise ValueError(f"unknown units {force_unit!r}, {torque_unit!r}")
    return BoxConfig(
        Calibration(
            float(fields["cfgcpf"]) / FORCE_UNITS[force_unit],
            float(fields["cfgcpt"]) / TORQUE_UNITS[torque_unit],
        ),
        float(fields["comrdtrate"]),
        force_unit,
        torque_unit,
    )


def read_box_config(host: str, port: int = 80, timeout_s: float = 2.0) -> BoxConfig:
    """A box's configuration from http://host:port/netftapi2.xml (OSError when unreachable,
    ValueError when the page is not one)."""
    with urllib.request.urlopen(f"http://{host}:{port}/{CONFIG_PAGE}", timeout=timeout_s) as r:
        page = r.read()
    try:
        return parse_box_config(page)
    except ET.ParseError as exc:
        raise ValueError(f"{CONFIG_PAGE} is not XML: {exc}") from exc


#: The box's communication settings page; ``comm.cgi?comrdtrate=<Hz>`` sets the RDT output rate
#: (ATI's Net F/T manual, "Communication Settings Page (comm.htm)": the box may round the value
#: up; ros2_net_ft_driver's AtiFTInterface::set_sampling_rate, range 1 to 7000 Hz).
RATE_PAGE = "comm.cgi"
RDT_RATE_RANGE_HZ = (1.0, 7000.0)


def set_box_rdt_rate(host: str, port: int, rate_hz: float, timeout_s: float = 2.0) -> BoxConfig:
    """Set a box's RDT output rate [Hz] through comm.cgi and read its configuration back
    (OSError when unreachable, ValueError for a rate out of range or a page that is not one);
    the caller checks the rate the box took (it may round up)."""
    lo, hi = RDT_RATE_RANGE_HZ
    if not lo <= rate_hz <= hi:
        raise ValueError(f"an RDT rate of {rate_hz:g} Hz is outside [{lo:g}, {hi:g}] Hz")
    url = f"http://{host}:{port}/{RATE_PAGE}?comrdtrate={int(round(rate_hz))}"
    with urllib.request.urlopen(url, timeout=timeout_s) as r:
        r.read()
    return read_box_config(host, port, timeout_s)


def box_config_xml(
    calibration: Calibration, rdt_rate_hz: float, force_unit: str = "N", torque_unit: str = "N-m"
) -> str:
    """A netftapi2.xml page (the fields RRG reads) for a box in the given units."""
    cpf = calibration.counts_per_force * FORCE_UNITS[force_unit]
    cpt = calibration.counts_per_torque * TORQUE_UNITS[torque_unit]
    return (
        '<?xml version="1.0"?>\n<netftapi2>'
        f"<cfgcpf>{cpf:.0f}</cfgcpf><cfgcpt>{cpt:.0f}</cfgcpt>"
        f"<scfgfu>{force_unit}</scfgfu><scfgtu>{torque_unit}</scfgtu>"
        f"<comrdtrate>{rdt_rate_hz:.0f}</comrdtrate></netftapi2>"
    )


# ------------------------------------------------------------------------ client
class RdtSample(NamedTuple):
    """One received record in SI units; ``received_s`` is time.monotonic() at reception."""

    box: str
    received_s: float
    rdt_sequence: int
    ft_sequence: int
    status: int
    wrench: np.ndarray  # (6,) [N, N, N, N m, N m, N m]


@dataclass(frozen=True)
class RdtHealth:
    """Counters of one client's stream since start()."""

    received: int  # well-formed records from the box
    lost: int  # records skipped by rdt_sequence jumps
    status_errors: int  # records with a non-zero status word
    length_errors: int  # datagrams of the wrong length (dropped)
    last_status: int  # status word of the newest record
    age_s: float  # since the newest datagram of any length [s]; inf if none
    rate_hz: float  # well-formed records over the last RDT_RATE_WINDOW [Hz]
    out_of_order: int = 0  # records older than the newest (dropped)
    socket_errors: int = 0  # receive errors, e.g. ICMP port unreachable when no box listens
    #: CPU time [s] of the receive thread while handling records (decode and on_sample: the
    #: bridge's guard), from its own thread clock (time.thread_time)
    cpu_s: float = 0.0


class RdtClient:
    """Streams one Net F/T box over RDT in a daemon thread.

    ``on_sample(sample)`` and ``on_fault(kind, detail)`` are called in the receive thread; keep
    them short. Fault kinds: 'length' (datagram dropped), 'status' (non-zero status word; the
    sample is still delivered with it), 'gap' (rdt_sequence jump: 'expected N got M, K lost';
    or an older record, dropped: 'expected N got M, out of order'), 'socket' (a receive error)
    and 'callback' (on_sample raised).
    """

    def __init__(
        self,
        host: str,
        port: int = RDT_PORT,
        calibration: Calibration = Calibration(),
        on_sample: Callable[[RdtSample], None] | None = None,
        on_fault: Callable[[str, str], None] | None = None,
        bind_host: str = "0.0.0.0",
        name: str = "",
    ):
        self.host = host
        self.port = int(port)
        self.calibration = calibration
        self.on_sample = on_sample
        self.on_fault = on_fault
        self.bind_host = bind_host
        self.name = name or host
        self._scale = calibration.scale
        self._sock: socket.socket | None = None
        self._addr: tuple[str, int] | None = None
        self._thread: threading.Thread | None = None
        self._running = False
        self._lock = threading.Lock()
        self._reset_counters()

    def _reset_counters(self) -> None:
        self._last_seq: int | None = None
        self._received = self._lost = self._status_errors = self._length_errors = 0
        self._out_of_order = self._socket_errors = 0
        self._cpu_s = 0.0  # [s] the receive thread spent on records (RdtHealth.cpu_s)
        self._last_status = 0
        self._last_rx = -np.inf
        self._started_s = time.monotonic()
        self._times: deque[float] = deque(maxlen=16384)  # > RDT_RATE_WINDOW at 7 kHz

    def set_calibration(self, calibration: Calibration) -> None:
        """Scale the records received from now on with ``calibration``."""
        self.calibration, self._scale = calibration, calibration.scale

    # -------------------------------------------------------------- commands
    def start(self) -> None:
        """Open the socket, ask the box for an endless real-time stream, start receiving."""
        if self._running:
            return
        self._reset_counters()
        ip = socket.gethostbyname(self.host)
        self._addr = (ip, self.port)
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RDT_RECEIVE_BUFFER)
            sock.bind((self.bind_host, 0))
            sock.settimeout(RDT_SOCKET_TIMEOUT)
        except OSError:
            sock.close()
            raise
        self._sock = sock
        self._running = True
        self._thread = threading.Thread(
            target=self._receive_loop, name=f"rdt-{self.name}", daemon=True
        )
        self._thread.start()
        self._send(RDT_CMD_START_REALTIME)

    def restream(self) -> None:
        """Ask again for an endless stream (e.g. after the box rebooted); the box restarts its
        rdt_sequence, so sequence tracking restarts too."""
        self._last_seq = None
        self._send(RDT_CMD_START_REALTIME)

    def bias(self) -> None:
        """Have the box subtract its current reading from then on (only when unloaded)."""
        self._send(RDT_CMD_SET_SOFTWARE_BIAS)

    def reset_latch(self) -> None:
        """Clear the box's latched threshold status."""
        self._send(RDT_CMD_RESET_THRESHOLD_LATCH)

    def stop(self) -> None:
        """Ask the box to stop, join the receive thread and close the socket (idempotent)."""
        if not self._running:
            return
        try:
            self._send(RDT_CMD_STOP)
        except OSError as e:
            log.warning("%s: RDT stop not sent: %s", self.name, e)
        self._running = False
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=10 * RDT_SOCKET_TIMEOUT)
        if self._sock is not None:
            self._sock.close()
        self._sock = self._thread = None

    def _send(self, command: int, sample_count: int = 0) -> None:
        if self._sock is None or self._addr is None:
            raise RuntimeError(f"RDT client {self.name} is not started")
        self._sock.sendto(encode_request(command, sample_count), self._addr)

    def __enter__(self) -> RdtClient:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    # -------------------------------------------------------------- state
    def health(self) -> RdtHealth:
        """The stream's counters now."""
        now = time.monotonic()
        with self._lock:
            times = list(self._times)
            h = dict(
                received=self._received,
                lost=self._lost,
                status_errors=self._status_errors,
                length_errors=self._length_errors,
                last_status=self._last_status,
                out_of_order=self._out_of_order,
                socket_errors=self._socket_errors,
                last_rx=self._last_rx,
            )
        h["cpu_s"] = self._cpu_s
        window = min(RDT_RATE_WINDOW, now - self._started_s)
        recent = len(times) - int(np.searchsorted(times, now - window, side="right"))
        last_rx = h.pop("last_rx")
        return RdtHealth(
            **h,
            age_s=now - last_rx if np.isfinite(last_rx) else float("inf"),
            rate_hz=recent / window if window > 0 else 0.0,
        )

    # -------------------------------------------------------------- receive thread
    def _fault(self, kind: str, detail: str) -> None:
        if self.on_fault is None:
            return
        try:
            self.on_fault(kind, detail)
        except Exception:
            log.exception("%s: RDT on_fault callback raised", self.name)

    def _receive_loop(self) -> None:
        sock, lock, times = self._sock, self._lock, self._times
        buf = bytearray(RECORD_SIZE + 28)  # room to see (and refuse) longer datagrams
        head = _RECORD_HEAD.unpack_from
        frombuffer, dtype = np.frombuffer, _COUNTS_DTYPE  # the scale may change (set_calibration)
        monotonic, thread_time, box, ip = time.monotonic, time.thread_time, self.name, self._addr[0]
        while self._running:
            try:
                n, addr = sock.recvfrom_into(buf)
            except TimeoutError:
                continue
            except OSError as e:
                if not self._running:
                    break
                self._socket_errors += 1
                self._fault("socket", str(e))
                continue
            busy_since, now = thread_time(), monotonic()
            if addr[0] != ip:  # not our box
                continue
            if n != RECORD_SIZE:
                with lock:
                    self._length_errors += 1
                    self._last_rx = now
                self._fault("length", f"{n}-byte datagram, expected {RECORD_SIZE}")
                continue
            seq, ft_seq, status = head(buf)
            last = self._last_seq
            if last is not None and seq != (last + 1) & _U32:
                expected = (last + 1) & _U32
                skipped = (seq - expected) & _U32
                if skipped >= 2**31:  # older than the newest record: drop it
                    with lock:
                        self._out_of_order += 1
                        self._last_rx = now
                    self._last_seq = seq  # a restarted stream is followed after one record
                    self._fault("gap", f"expected {expected} got {seq}, out of order")
                    continue
                with lock:
                    self._lost += skipped
                self._fault("gap", f"expected {expected} got {seq}, {skipped} lost")
            self._last_seq = seq
            wrench = frombuffer(buf, dtype, 6, _COUNTS_OFFSET) * self._scale
            with lock:
                self._received += 1
                self._last_rx = now
                self._last_status = status
                times.append(now)
                if status:
                    self._status_errors += 1
            if status:
                self._fault("status", f"0x{status:08x}")
            if self.on_sample is not None:
                try:
                    self.on_sample(RdtSample(box, now, seq, ft_seq, status, wrench))
                except Exception as e:
                    log.exception("%s: RDT on_sample callback raised", box)
                    self._fault("callback", repr(e))
            self._cpu_s += thread_time() - busy_since

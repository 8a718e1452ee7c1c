"""An emulated ATI Net F/T box: a UDP server speaking real RDT (rrg_hw_bridge.rdt) with the load
taken from a callable, box-side software bias, a latched status word, and injectable faults
(silence, random drops, delay, status word, malformed datagrams)."""

from __future__ import annotations

import logging
import math
import select
import socket
import struct
import threading
import time
import urllib.parse
from collections import deque
from collections.abc import Callable
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import numpy as np

from rrg_hw_bridge.config import RDT_RECORD_FORMAT
from rrg_hw_bridge.rdt import (
    CONFIG_PAGE,
    RATE_PAGE,
    RDT_CMD_RESET_THRESHOLD_LATCH,
    RDT_CMD_SET_SOFTWARE_BIAS,
    RDT_CMD_START_REALTIME,
    RDT_CMD_STOP,
    RDT_PORT,
    RDT_RATE_RANGE_HZ,
    RECORD_SIZE,
    Calibration,
    RdtProtocolError,
    box_config_xml,
    decode_request,
)

log = logging.getLogger(__name__)

_RECORD = struct.Struct(RDT_RECORD_FORMAT)
_U32 = 0xFFFF_FFFF
_I32_MIN, _I32_MAX = -(2**31), 2**31 - 1
#: Longest wait [s] for a request while no stream runs (how soon close() is noticed).
_IDLE_WAIT = 0.05
#: Records due at most this long ago [s] are still sent (back to back) when the box thread wakes
#: late; older ones are skipped, so a stall never becomes a burst and the schedule never drifts
#: (chosen: above the ~0.8 ms 99th-percentile wake-up lateness of a thread on a loaded 2-core VM).
MAX_CATCH_UP_S = 0.002


class FakeNetFtBox:
    """One emulated Net F/T box serving RDT on (host, port) from a daemon thread.

    ``wrench_source()`` returns the load on the sensor now, (6,) [N, N m]. The box answers
    START_REALTIME by streaming records at ``rate_hz`` to the requester's address (count 0 =
    forever, N = N records), STOP, SET_SOFTWARE_BIAS (stores the current raw counts, the
    ``zero_offset`` included, and subtracts them from the records generated after it) and
    RESET_THRESHOLD_LATCH (clears the status word);
    START_BUFFERED and malformed requests are ignored. rdt_sequence restarts at 1 with every
    START and counts every record generated, also those dropped or silenced, so a loss shows as
    a gap; ft_sequence counts internal samples at ``rate_hz`` since the box was created.
    ``port=0`` binds a free port (see ``.port``). With ``http_port`` the box also serves its
    configuration page, /netftapi2.xml (its calibration in N and N m, and its RDT rate), and
    comm.cgi, which sets the RDT rate, over HTTP on (host, http_port) (0: a free port, see
    ``.http_port``).
    """

    def __init__(
        self,
        host: str,
        wrench_source: Callable[[], np.ndarray],
        calibration: Calibration = Calibration(),
        rate_hz: float = 1000.0,
        port: int = RDT_PORT,
        noise_n: float = 0.0,
        noise_nm: float = 0.0,
        seed: int = 0,
        zero_offset=(0.0,) * 6,
        http_port: int | None = None,
    ):
        if rate_hz <= 0:
            raise ValueError(f"rate_hz must be positive, got {rate_hz}")
        self.host = host
        self.wrench_source = wrench_source
        self.calibration = calibration
        self.rate_hz = float(rate_hz)
        self._period = 1.0 / self.rate_hz
        self._per_unit = np.array(
            [calibration.counts_per_force] * 3 + [calibration.counts_per_torque] * 3
        )
        self._noise = np.array([noise_n] * 3 + [noise_nm] * 3, dtype=float)
        #: What the sensor reads unloaded [N, N m] until a bias removes it (a strain gauge's
        #: zero drifts with temperature and mounting; ATI's manual: bias before use).
        self.zero_offset = np.asarray(zero_offset, dtype=float).reshape(6)
        self._rng = np.random.default_rng(seed)
        self._lock = threading.Lock()
        # stream state (box thread)
        self._target: tuple[str, int] | None = None
        self._remaining: int | None = None
        self._rdt_seq = 0
        self._ft_seq = -1
        self._next_t: float | None = None
        self._pending: deque[tuple[float, bytes, tuple[str, int], float]] = deque()
        self._bias = np.zeros(6, dtype=np.int64)
        # faults (setters, any thread)
        self._status = 0
        self._silent = False
        self._drop_p = 0.0
        self._delay = 0.0
        self._wrong_length = False
        self._crossings: dict[float, float | None] = {}
        #: Counters: records generated / sent / dropped at random / withheld by silence,
        #: requests received and requests ignored (malformed or unsupported).
        self.records_generated = self.records_sent = self.records_dropped = 0
        self.records_silenced = self.requests = self.requests_ignored = 0
        self.source_errors = 0
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self._sock.bind((host, port))
        except OSError:
            self._sock.close()
            raise
        self._sock.setblocking(False)
        self.port = self._sock.getsockname()[1]
        self._t0 = time.monotonic()
        self._buf = bytearray(RECORD_SIZE)
        self._closed = False
        self._thread = threading.Thread(
            target=self._serve, name=f"fake-netft-{host}:{self.port}", daemon=True
        )
        self._thread.start()
        self._http: ThreadingHTTPServer | None = None
        self.http_port: int | None = None
        if http_port is not None:
            self._serve_config_page(host, http_port)

    # -------------------------------------------------------------- fault injection
    def silence(self, on: bool) -> None:
        """Stop (or resume) sending while rdt_sequence keeps counting."""
        self._silent = bool(on)

    def drop_probability(self, p: float) -> None:
        """Drop each record with probability p (seeded; 0 clears)."""
        if not 0.0 <= p <= 1.0:
            raise ValueError(f"drop probability {p} not in [0, 1]")
        self._drop_p = float(p)

    def delay(self, seconds: float) -> None:
        """Send each record this late [s] (0 clears)."""
        if seconds < 0:
            raise ValueError(f"delay {seconds} < 0")
        self._delay = float(seconds)

    def status_word(self, word: int) -> None:
        """Put this status word in every record until cleared (0) or the latch is reset."""
        if not 0 <= word <= _U32:
            raise ValueError(f"status word {word!r} is not a uint32")
        self._status = int(word)

    def wrong_length(self, on: bool) -> None:
        """Send 35-byte datagrams instead of records (or stop doing so)."""
        self._wrong_length = bool(on)

    # -------------------------------------------------------------- benchmarks
    def arm_crossing(self, threshold_n: float) -> None:
        """Start watching for the first sent record whose |force| exceeds threshold_n [N]."""
        with self._lock:
            self._crossings[float(threshold_n)] = None

    def first_crossing(self, threshold_n: float) -> float | None:
        """time.monotonic() at which the box first sent a record with |force| > threshold_n [N]
        since arm_crossing(threshold_n); None if not yet (or not armed)."""
        with self._lock:
            return self._crossings.get(float(threshold_n))

    # -------------------------------------------------------------- state
    @property
    def streaming(self) -> bool:
        """Whether a START_REALTIME stream is running."""
        return self._target is not None

    def set_rate(self, rate_hz: float) -> None:
        """Stream at ``rate_hz`` [Hz] from the next record on (comm.cgi's comrdtrate)."""
        if rate_hz <= 0:
            raise ValueError(f"rate_hz must be positive, got {rate_hz}")
        with self._lock:
            self.rate_hz, self._period = float(rate_hz), 1.0 / float(rate_hz)

    def _serve_config_page(self, host: str, port: int) -> None:
        """Serve /netftapi2.xml, and comm.cgi?comrdtrate=<Hz> (sets the RDT rate, clamped to
        RDT_RATE_RANGE_HZ; the emulated box does not round it), over HTTP on (host, port)
        from a daemon thread."""
        box = self

        class ConfigPage(BaseHTTPRequestHandler):
            def do_GET(self) -> None:
                url = urllib.parse.urlsplit(self.path)
                if url.path.lstrip("/") == RATE_PAGE:
                    query = urllib.parse.parse_qs(url.query)
                    try:
                        rate = float(query["comrdtrate"][0])
                    except (KeyError, ValueError):
                        self.send_error(400)
                        return
                    box.set_rate(float(np.clip(rate, *RDT_RATE_RANGE_HZ)))
                    page = b"<html><body>Communication settings saved</body></html>"
                    content_type = "text/html"
                elif url.path.lstrip("/") == CONFIG_PAGE:
                    page = box_config_xml(box.calibration, box.rate_hz).encode()
                    content_type = "text/xml"
                else:
                    self.send_error(404)
                    return
                self.send_response(200)
                self.send_header("Content-Type", content_type)
                self.send_header("Content-Length", str(len(page)))
                self.end_headers()
                self.wfile.write(page)

            def log_message(self, *args) -> None:  # quiet, as the box is
                pass

        try:
            self._http = ThreadingHTTPServer((host, port), ConfigPage)
        except OSError:
            self.close()
            raise
        self.http_port = self._http.server_address[1]
        threading.Thread(
            target=self._http.serve_forever, name=f"fake-netft-http-{host}", daemon=True
        ).start()

    def close(self) -> None:
        """Stop the box thread and close the socket (idempotent)."""
        if self._closed:
            return
        self._closed = True
        if self._http is not None:
            self._http.shutdown()
            self._http.server_close()
        if self._thread is not threading.current_thread():
            self._thread.join(timeout=1.0)
        self._sock.close()

    def __enter__(self) -> FakeNetFtBox:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -------------------------------------------------------------- box thread
    def _raw_counts(self) -> np.ndarray:
        """(6,) int64 readings [counts] of the load now, noise included, before the bias."""
        w = np.asarray(self.wrench_source(), dtype=float) + self.zero_offset
        if self._noise.any():
            w = w + self._rng.normal(size=6) * self._noise
        return np.rint(w * self._per_unit).astype(np.int64)

    def _serve(self) -> None:
        sock = self._sock
        while not self._closed:
            now = time.monotonic()
            while self._pending and self._pending[0][0] <= now:
                _, data, target, force = self._pending.popleft()
                self._send(data, target, force)
            if self._target is not None and self._next_t is not None and now >= self._next_t:
                next_t = self._next_t + self._period
                if now - next_t > MAX_CATCH_UP_S:  # a stall: skip ahead on the grid, no burst
                    next_t += (math.floor((now - next_t) / self._period) + 1) * self._period
                self._next_t = next_t
                self._generate(now)  # ends the stream (next_t None) after a counted one
                continue
            wake = now + _IDLE_WAIT
            if self._target is not None and self._next_t is not None:
                wake = min(wake, self._next_t)
            if self._pending:
                wake = min(wake, self._pending[0][0])
            try:
                readable, _, _ = select.select([sock], [], [], max(0.0, wake - time.monotonic()))
            except (OSError, ValueError):  # closed under us
                break
            if readable:
                self._handle_requests()

    def _handle_requests(self) -> None:
        while True:
            try:
                data, addr = self._sock.recvfrom(64)
            except BlockingIOError:
                return
            except ConnectionError:  # ICMP port unreachable from records sent to a gone client
                continue
            except OSError:
                return
            self.requests += 1
            try:
                command, count = decode_request(data)
            except RdtProtocolError:
                self.requests_ignored += 1
                continue
            if command == RDT_CMD_START_REALTIME:
                self._target = addr
                self._remaining = count or None
                self._rdt_seq = 0
                self._pending.clear()
                self._next_t = time.monotonic()
            elif command == RDT_CMD_STOP:
                self._target = self._next_t = self._remaining = None
                self._pending.clear()
            elif command == RDT_CMD_SET_SOFTWARE_BIAS:
                try:
                    self._bias = self._raw_counts()
                except Exception:
                    self.source_errors += 1
                    log.exception("fake Net F/T %s: wrench_source raised", self.host)
            elif command == RDT_CMD_RESET_THRESHOLD_LATCH:
                self._status = 0
            else:  # START_BUFFERED (several records per datagram) and unknown commands
                self.requests_ignored += 1

    def _generate(self, now: float) -> None:
        try:
            raw = self._raw_counts()
        except Exception:
            self.source_errors += 1
            log.exception("fake Net F/T %s: wrench_source raised", self.host)
            return
        counts = np.clip(raw - self._bias, _I32_MIN, _I32_MAX)
        self._rdt_seq = (self._rdt_seq + 1) & _U32
        # the internal sample due now, and never the same sample twice
        self._ft_seq = max(self._ft_seq + 1, int((now - self._t0) * self.rate_hz))
        ft_seq = self._ft_seq & _U32
        _RECORD.pack_into(self._buf, 0, self._rdt_seq, ft_seq, self._status, *counts.tolist())
        target = self._target
        self.records_generated += 1
        if self._remaining is not None:
            self._remaining -= 1
            if self._remaining <= 0:
                self._target = self._next_t = self._remaining = None
        if self._silent:
            self.records_silenced += 1
            return
        if self._drop_p > 0.0 and self._rng.random() < self._drop_p:
            self.records_dropped += 1
            return
        if self._wrong_length:
            data, force = bytes(self._buf[: RECORD_SIZE - 1]), -1.0  # not a record
        else:
            data = bytes(self._buf)
            force = math.hypot(*counts[:3].tolist()) / self.calibration.counts_per_force
        if self._delay > 0.0:
            self._pending.append((now + self._delay, data, target, force))
        else:
            self._send(data, target, force)

    def _send(self, data: bytes, target: tuple[str, int], force: float) -> None:
        t = time.monotonic()  # before sendto: the client may act on the record before it returns
        try:
            self._sock.sendto(data, target)
        except OSError:  # a client that went away (ICMP): the real box keeps going too
            return
        self.records_sent += 1
        if self._crossings:
            with self._lock:
                for threshold, first in self._crossings.items():
                    if first is None and force > threshold:
                        self._crossings[threshold] = t

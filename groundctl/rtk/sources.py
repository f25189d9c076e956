"""Where corrections come from: a file, a TCP server, a serial port, an NTRIP caster.

``SOURCE`` text (``--rtk``):

- ``serial:/dev/ttyACM0:115200`` — a serial port (pyserial, read in a thread);
- ``tcp:HOST:PORT`` or ``HOST:PORT`` — a TCP server sending raw RTCM3;
- ``ntrip://[USER:PASS@]HOST[:PORT]/MOUNT`` — an NTRIP v1/v2 caster (GET /MOUNT with
  Basic auth and ``Ntrip-Version: Ntrip/2.0``; "ICY 200 OK" and HTTP 200 accepted,
  chunked transfer decoded).  Given the field's position, the client tells the caster
  where it is with an NMEA GGA sentence (the ``Ntrip-GGA`` header, then in the stream
  once connected and every ``GGA_PERIOD_S``): network (VRS) mount points send nothing
  until they hear one;
- anything else — a file of RTCM3 frames, replayed one epoch per ``1/epoch_hz``
  seconds of the clock, looping (rehearsal and tests).

Every source is an async iterator of byte chunks (:meth:`RtkSource.chunks`); none
blocks the event loop (the serial port and the file are read in a thread).
"""

from __future__ import annotations

import asyncio
import base64
import re
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from urllib.parse import unquote, urlsplit

from groundctl.clock import Clock, sleep_until
from groundctl.errors import EXIT_USAGE, GroundctlError
from groundctl.rtk.rtcm import RtcmFramer, split_epochs


class RtkSourceError(GroundctlError):
    """A correction source that cannot be used (bad text, unreadable file, refused)."""

    exit_code = EXIT_USAGE

    def __init__(self, source: str, why: str) -> None:
        super().__init__(f"--rtk {source}: {why}")
        self.source = source
        self.why = why


@dataclass(frozen=True)
class SourceSpec:
    """A parsed ``--rtk SOURCE``."""

    kind: str
    """``file``, ``tcp``, ``serial`` or ``ntrip``."""
    text: str
    """As given (the password hidden)."""
    host: str = ""
    port: int = 0
    path: str = ""
    """File path, serial device, or NTRIP mount point."""
    baud: int = 0
    user: str | None = None
    password: str | None = None


#: Seconds between the GGA sentences an NTRIP client sends (casters time a silent
#: network rover out after about a minute).
GGA_PERIOD_S = 10.0


def gga_sentence(lat: float, lon: float, alt_m: float, utc: datetime) -> str:
    """An NMEA 0183 GGA sentence (``$GPGGA,...*CS``, with CR LF) for a rover at ``lat``,
    ``lon`` (degrees) and ``alt_m`` (m above mean sea level) at ``utc``: fix quality 1,
    12 satellites, HDOP 1.0, the geoid separation unknown (0)."""
    if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
        raise ValueError(f"no such position: {lat}, {lon}")

    def dm(value: float, width: int) -> str:
        deg = int(abs(value))
        minutes = (abs(value) - deg) * 60.0
        if round(minutes, 5) >= 60.0:
            deg, minutes = deg + 1, 0.0
        return f"{deg:0{width}d}{minutes:08.5f}"
    body = (f"GPGGA,{utc:%H%M%S}.{utc.microsecond // 10000:02d},{dm(lat, 2)},"
            f"{'N' if lat >= 0 else 'S'},{dm(lon, 3)},{'E' if lon >= 0 else 'W'},1,12,1.0,"
            f"{alt_m:.1f},M,0.0,M,,")
    checksum = 0
    for byte in body.encode("ascii"):
        checksum ^= byte
    return f"${body}*{checksum:02X}\r\n"


_HOSTPORT = re.compile(r"^(?:tcp:)?(?P<host>[A-Za-z0-9.\-]+|\[[0-9a-fA-F:]+\]):(?P<port>\d+)$")


def parse_source(text: str) -> SourceSpec:
    """``--rtk``'s text as a :class:`SourceSpec`; RtkSourceError if it is none."""
    if text.startswith("serial:"):
        dev, _, baud = text[len("serial:"):].rpartition(":")
        if not dev or not baud.isdigit() or int(baud) <= 0:
            raise RtkSourceError(text, "a serial source is serial:DEVICE:BAUD, e.g. "
                                       "serial:/dev/ttyACM0:115200")
        return SourceSpec("serial", text, path=dev, baud=int(baud))
    if text.startswith("ntrip://"):
        url = urlsplit(text)
        mount = url.path.lstrip("/")
        try:
            port = url.port or 2101
        except ValueError:
            port = -1
        if not url.hostname or not mount or port <= 0:
            raise RtkSourceError(text, "an NTRIP source is ntrip://[USER:PASS@]HOST[:PORT]/MOUNT")
        shown = text if url.password is None else text.replace(f":{url.password}@", ":***@", 1)
        return SourceSpec("ntrip", shown, host=url.hostname, port=port, path=mount,
                          user=unquote(url.username) if url.username else None,
                          password=unquote(url.password) if url.password else None)
    m = _HOSTPORT.match(text)
    if m and (text.startswith("tcp:") or not Path(text).exists()):
        port = int(m["port"])
        if not 0 < port < 65536:
            raise RtkSourceError(text, f"port {port} is not within 1..65535")
        return SourceSpec("tcp", text, host=m["host"].strip("[]"), port=port)
    if text.startswith("tcp:"):
        raise RtkSourceError(text, "a TCP source is tcp:HOST:PORT")
    path = Path(text)
    if not path.is_file():
        raise RtkSourceError(text, "not a file of RTCM3, a serial:DEVICE:BAUD, a HOST:PORT "
                                   "or an ntrip://HOST:PORT/MOUNT")
    return SourceSpec("file", text, path=text)


def load_epochs(path: Path) -> list[list[bytes]]:
    """A file's good RTCM3 frames grouped in epochs; RtkSourceError if it holds none."""
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise RtkSourceError(str(path), f"cannot read it: {exc.strerror or exc}") from None
    framer = RtcmFramer()
    frames = framer.feed(data)
    if not frames:
        raise RtkSourceError(str(path), f"no valid RTCM3 frame in {len(data)} bytes "
                                        f"({framer.stats.bad_crc} with a bad CRC)")
    return split_epochs(frames)


class RtkSource:
    """An async iterator of byte chunks from one :class:`SourceSpec`."""

    def __init__(self, spec: SourceSpec, clock: Clock, *, epoch_hz: float = 1.0,
                 connect_timeout_s: float = 10.0,
                 position: tuple[float, float, float] | None = None,
                 utc: Callable[[], datetime] = lambda: datetime.now(UTC)) -> None:
        """``position`` (lat, lon degrees, alt m) is where the rovers are, for an NTRIP
        caster's GGA (None: none is sent); ``utc`` tells the time of day for it."""
        if not epoch_hz > 0:
            raise ValueError(f"`epoch_hz` must be positive, got {epoch_hz}")
        self.spec = spec
        self.position = position
        self.utc = utc
        self.gga_sent = 0
        """GGA sentences written to an NTRIP caster (the header's included)."""
        self.clock = clock
        self.epoch_hz = epoch_hz
        self.connect_timeout_s = connect_timeout_s
        self.epochs: list[list[bytes]] | None = (
            load_epochs(Path(spec.path)) if spec.kind == "file" else None)
        self.loops = 0
        """Times a file was replayed from its start again."""

    def chunks(self) -> AsyncIterator[bytes]:
        kind = self.spec.kind
        if kind == "file":
            return self._file()
        if kind == "tcp":
            return self._tcp()
        if kind == "ntrip":
            return self._ntrip()
        return self._serial()

    async def _file(self) -> AsyncIterator[bytes]:
        assert self.epochs is not None
        period = 1.0 / self.epoch_hz
        due = self.clock.now()
        while True:
            for epoch in self.epochs:
                await sleep_until(self.clock, due)
                due = max(due + period, self.clock.now() - period)
                yield b"".join(epoch)
            self.loops += 1

    async def _open(self) -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
        try:
            return await asyncio.wait_for(
                asyncio.open_connection(self.spec.host, self.spec.port), self.connect_timeout_s)
        except (TimeoutError, OSError) as exc:
            where = f"{self.spec.host}:{self.spec.port}"
            raise RtkSourceError(self.spec.text, f"cannot connect to {where}: "
                                                 f"{exc or 'timed out'}") from None

    async def _tcp(self) -> AsyncIterator[bytes]:
        reader, writer = await self._open()
        try:
            while data := await reader.read(4096):
                yield data
        finally:
            writer.close()

    async def _ntrip(self) -> AsyncIterator[bytes]:
        spec = self.spec
        reader, writer = await self._open()
        gga: asyncio.Task[None] | None = None
        try:
            lines = [f"GET /{spec.path} HTTP/1.1", f"Host: {spec.host}:{spec.port}",
                     "Ntrip-Version: Ntrip/2.0", "User-Agent: NTRIP groundctl/0.1",
                     "Connection: close"]
            if spec.user is not None:
                token = base64.b64encode(f"{spec.user}:{spec.password or ''}".encode()).decode()
                lines.append(f"Authorization: Basic {token}")
            if self.position is not None:
                lines.append(f"Ntrip-GGA: {self._gga().strip()}")
                self.gga_sent += 1
            writer.write(("\r\n".join(lines) + "\r\n\r\n").encode())
            await writer.drain()
            status = (await asyncio.wait_for(reader.readline(), self.connect_timeout_s)
                      ).decode("latin-1").strip()
            chunked = False
            if status.startswith("ICY 200"):
                pass  # NTRIP v1: the data follows at once
            elif re.match(r"^HTTP/1\.[01] 200\b", status):
                while True:
                    header = (await reader.readline()).decode("latin-1").strip()
                    if not header:
                        break
                    name, _, value = header.partition(":")
                    if name.strip().lower() == "transfer-encoding" \
                            and "chunked" in value.lower():
                        chunked = True
            else:
                why = "source table (no such mount point)" if "SOURCETABLE" in status \
                    else repr(status[:80])
                raise RtkSourceError(spec.text, f"the caster refused: {why}")
            if self.position is not None:
                gga = asyncio.create_task(self._send_gga(writer))
            if chunked:
                while True:
                    size_line = (await reader.readline()).decode("latin-1").strip()
                    size = int(size_line.split(";")[0] or "0", 16)
                    if size == 0:
                        return
                    yield await reader.readexactly(size)
                    await reader.readline()
            else:
                while data := await reader.read(4096):
                    yield data
        finally:
            if gga is not None:
                gga.cancel()
            writer.close()

    def _gga(self) -> str:
        assert self.position is not None
        return gga_sentence(*self.position, self.utc())

    async def _send_gga(self, writer: asyncio.StreamWriter) -> None:
        """Once connected (NTRIP v1 casters read it from the stream, not a header), then
        every GGA_PERIOD_S of the clock, until the stream ends."""
        try:
            while not writer.is_closing():
                writer.write(self._gga().encode("ascii"))
                self.gga_sent += 1
                await writer.drain()
                await asyncio.sleep(self.clock.wall_interval(GGA_PERIOD_S))
        except (ConnectionError, OSError):
            return  # the reading side sees the stream end and says so

    async def _serial(self) -> AsyncIterator[bytes]:
        try:
            import serial  # type: ignore[import-untyped]  # pyserial, only when asked for
        except ImportError:
            raise RtkSourceError(self.spec.text, "reading a serial port needs pyserial "
                                                 "(pip install pyserial)") from None
        try:
            port = await asyncio.to_thread(serial.Serial, self.spec.path, self.spec.baud,
                                           timeout=0.2)
        except (OSError, ValueError, serial.SerialException) as exc:
            raise RtkSourceError(self.spec.text, f"cannot open it: {exc}") from None
        try:
            while True:
                data = await asyncio.to_thread(port.read, 4096)
                if data:
                    yield bytes(data)
        finally:
            port.close()

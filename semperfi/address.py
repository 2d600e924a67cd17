"""Addresses of the other ends SemperFi talks to, in the forms ArduPilot and pymavlink users type them:
tcp:HOST:PORT (connect), udpin:HOST:PORT (listen), udpout:HOST:PORT (send), or a serial device (/dev/ttyACM0,
COM3), optionally with ,BAUD."""

from __future__ import annotations

from dataclasses import dataclass

NETWORK_FORMS = ("tcp", "tcpin", "udp", "udpin", "udpout", "udpbcast")
DEFAULT_BAUD = 115200


@dataclass(frozen=True)
class Address:
    form: str                 # one of NETWORK_FORMS, or "serial"
    host: str = ""
    port: int = 0
    device: str = ""
    baud: int = DEFAULT_BAUD


def parse_address(url: str, what: str = "address") -> Address:
    """The address, checked; ValueError (one line naming `what`) for anything else."""
    form, _, rest = url.partition(":")
    if form in NETWORK_FORMS:
        host, _, port = rest.rpartition(":")
        if not host or not port.isdigit() or not 0 < int(port) < 65536:
            raise ValueError(f"{what} {url!r}: expected {form}:HOST:PORT with a port of 1-65535")
        return Address(form, host, int(port))
    device, _, baud = url.partition(",")
    if device.startswith("/dev/") or device.upper().startswith("COM"):
        if baud and not (baud.isdigit() and 1200 <= int(baud) <= 4_000_000):
            raise ValueError(f"{what} {url!r}: the baud rate after ',' must be 1200 to 4000000")
        return Address("serial", device=device, baud=int(baud) if baud else DEFAULT_BAUD)
    raise ValueError(f"{what} {url!r}: expected tcp:HOST:PORT, udpin:HOST:PORT, udpout:HOST:PORT or a serial "
                     "device such as /dev/ttyACM0")

"""GPS_INPUT's spacing as an autopilot sees it, while the receiver keeps both cores busy.

    .venv/bin/python benchmarks/bench_gps_input_spacing.py [--seconds 20] [--load 2]

ArduPilot calls a MAVLink GPS unhealthy when its messages average more than ~215 ms apart. A FixStream sends GPS_INPUT
at 10 Hz to a local UDP socket (MavlinkGpsOut) while `--load` threads do what the receiver does between fixes
(numpy FFTs of acquisition blocks, which hold the GIL between calls) and a fix arrives every 100 ms; the receiving
end timestamps every datagram. Prints the intervals' mean, standard deviation, 99th percentile and maximum, and how
many exceeded 215 ms.
"""

import argparse
import socket
import threading
import time

import numpy as np

from semperfi.gps.geometry import geodetic_to_ecef
from semperfi.receiver.fix_stream import FixStream
from semperfi.receiver.gps_input import MavlinkGpsOut
from semperfi.receiver.types import Fix


def a_fix() -> Fix:
    return Fix(t_rx_s=1.0, gps_week=2190, gps_tow_s=518400.0, pos_ecef_m=geodetic_to_ecef(0.739, -1.2408, 10.0),
               vel_ecef_m_s=np.zeros(3), clock_bias_m=0.0, clock_drift_m_s=0.0, lat_deg=42.34, lon_deg=-71.09,
               height_m=10.0, n_sats=8, prns=tuple(range(1, 9)), pdop=1.8, hdop=0.9, vdop=1.5, residual_rms_m=0.5,
               raim="pass", hpl_m=6.0, vpl_m=9.0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--load", type=int, default=2, help="busy threads beside the stream")
    args = ap.parse_args()
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(1.0)
    sink = MavlinkGpsOut(f"udpout:127.0.0.1:{rx.getsockname()[1]}")
    stream = FixStream(sink.send)
    stop = threading.Event()

    def busy():
        x = np.random.default_rng(0).normal(size=200_000).astype(np.complex64)
        while not stop.is_set():
            np.fft.ifft(np.fft.fft(x) * np.conj(np.fft.fft(x[::-1])))

    def fixes():
        while not stop.wait(0.1):
            stream.update(a_fix())

    threads = [threading.Thread(target=busy, daemon=True) for _ in range(args.load)]
    threads.append(threading.Thread(target=fixes, daemon=True))
    for t in threads:
        t.start()
    arrivals = []
    t_end = time.monotonic() + args.seconds
    while time.monotonic() < t_end:
        try:
            rx.recv(1024)
        except socket.timeout:
            continue
        arrivals.append(time.monotonic())
    stop.set()
    stream.close()
    sink.close()
    gaps_ms = np.diff(arrivals) * 1e3
    print(f"{len(arrivals)} GPS_INPUT in {args.seconds:g} s with {args.load} busy threads: interval mean "
          f"{gaps_ms.mean():.1f} ms, std {gaps_ms.std():.2f} ms, p99 {np.percentile(gaps_ms, 99):.1f} ms, max "
          f"{gaps_ms.max():.1f} ms, {int((gaps_ms > 215).sum())} over 215 ms")


if __name__ == "__main__":
    main()

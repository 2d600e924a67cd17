"""The Adversarial Peak Identifier on a stream of samples: follow every candidate peak through the vehicle's
maneuver, then decide peak by peak (identifier.identify_peaks) whose range followed the motion the INS measured.

When the maneuver window (found in the INS track) begins, every peak of the latest examination gets a tracking
channel of its own on the raw samples: both peaks of each PRN awaiting a verdict, and the single peak of every
other PRN (they make the consensus clock). A channel's accumulated carrier phase is its peak's range change
(-wavelength x integrated Doppler), to millimetres. Two peaks closer than SEPARATE_CHIPS pull one another's loops
and are not followed apart: such a PRN stays undecided. When the window ends, the histories go to the identifier
with each satellite's line of sight and its own range change over the window (from the ephemeris).
"""

import math
from dataclasses import dataclass, replace

import numpy as np

from ..gps import L1_WAVELENGTH_M, chips_apart, enu_rotation, satellite_position
from ..receiver import Channel, LoopConfig, NEXT_SAMPLE, Peak, initial_state
from .identifier import INS_DRIFT_M, REQUIRED_SPREAD_M, ImuTrack, LineOfSight, PeakHistory, PeakVerdict, identify_peaks
from .imu_track import find_maneuver

MAX_CLOCK_S = 1e9                # a vehicle clock beyond this is not one (hostile input)
MAX_REASON_CHARS = 200           # a failure's reason as kept (a peer's words, hostile input)
SEPARATE_CHIPS = 1.5          # closer peaks share a tracking loop's discriminator
FOLLOW_LOOP = LoopConfig(pull_in_ms=300, min_cn0_dbhz=20.0, lost_windows=10)
HISTORY_EVERY_MS = 20         # one range sample per 20 ms is plenty for a 10-20 s maneuver
SETTLE_S = 0.5                # the window's first half second: the followers' loops settle
FLIGHT_TIME_S = 0.075         # signal flight time, for the satellites' transmit instants (its changes are negligible)
# carrier ranges are good to millimetres: what remains is the INS drift over the maneuver -- a code-range tolerance
# (4.5 m) would let a spoofed peak with a small signature pass
CARRIER_RANGE_TOL_M = INS_DRIFT_M + 0.5   # the tolerance less the drift: the carrier ranges' own error
MAX_DRIFT_BOUND_M = 50.0      # beyond this a track decides nothing (the maneuver fails); without GPS 20 s state 27 m


class PeakFollower:
    """One candidate peak followed by its own tracking channel; its range history from the carrier."""

    def __init__(self, prn: int, peak_id: int, peak: Peak, peak_sample: int, start_sample: int, fs_hz: float,
                 if_hz: float):
        self.prn, self.peak_id, self.peak, self.fs_hz = prn, peak_id, peak, fs_hz
        st = initial_state(peak.code_phase_chips, peak_sample, peak.doppler_hz, fs_hz, start_sample)
        self.channel = Channel(prn, fs_hz, if_hz, st, FOLLOW_LOOP)
        self.t_s: list[float] = []
        self.carrier_range_m: list[float] = []
        self.cn0_dbhz: list[float] = []

    @property
    def next_sample(self) -> float:
        return float(self.channel.st[NEXT_SAMPLE])

    def feed(self, x: np.ndarray, base_sample: int) -> None:
        prompts, first = self.channel.process(x, base_sample)
        ch = self.channel
        for ms in range(first, first + prompts.size):
            if ms < FOLLOW_LOOP.pull_in_ms or ms % HISTORY_EVERY_MS:
                continue
            i = ms % ch.HISTORY_MS
            self.t_s.append(float(ch.epoch_sample[i]) / self.fs_hz)
            self.carrier_range_m.append(-L1_WAVELENGTH_M * float(ch.carrier_cycles[i]))
            self.cn0_dbhz.append(float(ch.cn0_dbhz))

    def mean_cn0_dbhz(self) -> float:
        values = [v for v in self.cn0_dbhz if np.isfinite(v)]
        return float(np.mean(values)) if values else float("nan")

    def history(self) -> PeakHistory | None:
        if len(self.t_s) < 10 or not self.channel.locked:
            return None
        # the carrier's range (the integral of the Doppler), to millimetres: the code's metre of noise would blur
        # a legitimate peak's fit and hide a spoofed peak whose line of sight moved little
        return PeakHistory(self.prn, self.peak_id, np.array(self.t_s), np.array(self.carrier_range_m))

    def peak_at(self, sample: int) -> Peak | None:
        """Where this peak is at an absolute sample (acquisition's convention: the chip arriving then)."""
        around = self.channel.epoch_around(sample)
        if around is None:
            return None
        return Peak(self.prn, around[1] * 1023.0, self.channel.doppler_at(sample), self.peak.metric, self.peak.cn0_dbhz)


@dataclass(frozen=True)
class Identification:
    verdicts: tuple[PeakVerdict, ...]
    followers: dict                # (prn, peak_id) -> PeakFollower


def lines_of_sight(prns, ephemeris_of, fix, t_s: np.ndarray) -> dict[int, LineOfSight]:
    """Each satellite's unit line of sight (NED, from the fix's position) and its own range change over t_s.

    ephemeris_of(prn, tow_s) gives the ephemeris; fix is any recent fix (spoofed or not: a line of sight moves by
    1e-4 rad per kilometre of position error). Receiver time t_s maps to GPS time through the fix."""
    pos = np.asarray(fix.pos_ecef_m, dtype=float)
    enu = enu_rotation(np.radians(fix.lat_deg), np.radians(fix.lon_deg))
    out = {}
    for prn in prns:
        tow = fix.gps_tow_s + (t_s - fix.t_rx_s) - FLIGHT_TIME_S
        eph = ephemeris_of(prn, float(tow[0]))
        if eph is None:
            continue
        sat = satellite_position(eph, tow)
        rng = np.linalg.norm(sat - pos, axis=1)
        u_enu = ((sat - pos) / rng[:, None]) @ enu.T
        u_ned = np.column_stack([u_enu[:, 1], u_enu[:, 0], -u_enu[:, 2]])
        out[prn] = LineOfSight(prn, tuple(float(x) for x in u_ned[0]), t_s, rng - rng[0], np.gradient(rng, t_s),
                               u_ned - u_ned[0])
    return out


def sky(prns, ephemeris_of, fix) -> list[dict]:
    """Azimuth and elevation (degrees) from the fix of each PRN with an ephemeris: the alarm carries them so the flight
    side draws a maneuver that moves along every one (flight/link.py)."""
    out = []
    for prn, los in sorted(lines_of_sight(prns, ephemeris_of, fix, np.array([fix.t_rx_s, fix.t_rx_s + 1.0])).items()):
        north, east, down = los.u_ned
        out.append({"prn": prn, "az_deg": round(float(np.degrees(np.arctan2(east, north)) % 360.0), 2),
                    "el_deg": round(float(np.degrees(np.arcsin(np.clip(-down, -1.0, 1.0)))), 2)})
    return out


class ManeuverIdentifier:
    """Follows candidate peaks through the maneuver window of an INS track, and identifies them at its end."""

    def __init__(self, track: ImuTrack | None, fs_hz: float, if_hz: float = 0.0):
        """track None: it comes later (LinkedManeuver, from the flight side)."""
        self.fs_hz, self.if_hz = fs_hz, if_hz
        self._unflown(track)

    def _unflown(self, track: ImuTrack | None) -> None:
        """The state before any peak is followed, for this track."""
        self.track = track
        self.window_s = find_maneuver(track) if track is not None else None
        self.drift_bound_m = INS_DRIFT_M   # how far the INS track may be from the flight at the window's end
        self.followers: dict[tuple[int, int], PeakFollower] = {}
        self._buf = np.empty(0, dtype=np.complex64)
        self._base = 0
        self.started = self.ended = False

    def request(self, t_s: float, prn: int) -> None:
        """An alarm waits for the maneuver (a recorded track's maneuver comes when it comes)."""

    def retry(self, t_s: float) -> bool:
        """Whether a fresh maneuver was asked for after a failed one (a recording has the one it has)."""
        return False

    def news(self) -> list[tuple[str, dict]]:
        """What went wrong since the last call, as events (a recorded track has nothing to tell)."""
        return []

    def pending(self, t_s: float) -> bool:
        """Whether a verdict can still come from this track's maneuver (it has not begun by t_s)."""
        return self.window_s is not None and not self.started and t_s < self.window_s[0]

    def due_to_start(self, t_s: float) -> bool:
        return self.window_s is not None and not self.started and t_s >= self.window_s[0]

    def expected(self) -> bool:
        """Whether a maneuver is on its way or under way (the looks follow its peaks): a recording's, until it ends."""
        return self.window_s is not None and not self.ended

    def due_to_end(self, t_s: float) -> bool:
        return self.started and not self.ended and t_s >= self.window_s[1]

    def start(self, peaks_by_prn: dict[int, list[Peak]], peak_sample: int, window: np.ndarray) -> None:
        """Follow these peaks from peak_sample (the first sample of `window`, where their code phases hold)."""
        self.started = True
        for prn, peaks in peaks_by_prn.items():
            if len(peaks) > 1 and chips_apart(peaks[0].code_phase_chips, peaks[1].code_phase_chips) < SEPARATE_CHIPS:
                continue
            for k, p in enumerate(peaks):
                self.followers[(prn, k)] = PeakFollower(prn, k, p, peak_sample, peak_sample, self.fs_hz, self.if_hz)
        self._buf, self._base = np.asarray(window, dtype=np.complex64), peak_sample
        self._feed()

    def push(self, chunk: np.ndarray) -> None:
        if not self.started or self.ended:
            return
        self._buf = np.concatenate([self._buf, chunk])
        self._feed()

    def _feed(self) -> None:
        for f in self.followers.values():
            f.feed(self._buf, self._base)
        keep = min([int(f.next_sample) for f in self.followers.values()] + [self._base + self._buf.size])
        drop = max(0, keep - self._base)
        self._buf, self._base = self._buf[drop:], self._base + drop

    def identify(self, ephemeris_of, fix) -> Identification:
        """The per-peak verdicts at the window's end (peaks that lost lock or lack an ephemeris are left out)."""
        self.ended = True
        if self.track is None or self.window_s is None:
            return Identification((), self.followers)
        t0, t1 = self.window_s
        histories = [h for h in (f.history() for f in self.followers.values()) if h is not None]
        # the satellites' own motion over the whole span the histories cover (np.interp would hold it still beyond)
        span = [h for h in histories if h.t_s[0] <= t0 + SETTLE_S + 1.0 and h.t_s[-1] >= t1 - 1.0]
        t = np.linspace(min([h.t_s[0] for h in span] + [t0]), max([h.t_s[-1] for h in span] + [t1]), 201)
        los = lines_of_sight(sorted({h.prn for h in span}), ephemeris_of, fix, t) if fix is not None else {}
        usable = [h for h in span if h.prn in los]
        tol_m = CARRIER_RANGE_TOL_M - INS_DRIFT_M + max(INS_DRIFT_M, self.drift_bound_m)
        verdicts = identify_peaks(usable, los, self.track, range_tol_m=tol_m) if len(usable) >= 3 else []
        return Identification(tuple(verdicts), self.followers)


class LinkedManeuver(ManeuverIdentifier):
    """The identifier live, over the link to the flight side (flight/link.py's schema; `channel` has send(type,
    payload) and poll() -> [(type, payload)], and is built outside the defence, which never imports flight/).

    On the first alarm that waits for it, an "alarm" goes out as soon as the receiver can use a verdict (`ready()`:
    it has a fix, so the satellites' lines of sight are known), carrying the lines of sight of the PRNs to decide
    (`sky()`, as the function sky gives them) for the flight side to move along; when the flight side answers
    "maneuver_request" (it has drawn a maneuver and is about to fly it) every candidate peak is followed from the
    next look on; its "maneuver_done" brings the IMU track (t_s on the vehicle's clock, mapped to the receiver's
    sample clock by the pair the request made: the vehicle's time as the flight side sent it, the sample time as
    the receiver read it -- off by the receiver's latency behind the antenna, a fraction of a second live) and,
    once the samples have reached the track's end, the peaks are
    identified and a "verdict" goes back. No answer within ACCEPT_S, or no track within TRACK_S of signal time: the
    maneuver has failed, the waiting alarms are examined afresh, and the policy's guess applies from then on.

    A failed maneuver is asked for again (`retry`, up to MAX_ATTEMPTS in all) while cancellations made on a guess
    wait for a verdict: a flight side that aborted one at its geofence, or did not answer, left a recovered takeover
    unjudged and the autopilot without a trusted position to the end (ArduCopter SITL, x1). A retry is asked RETRY_S
    after the failure (the flight side has levelled the vehicle); no alarm waits for it: the guesses stand meanwhile,
    and it judges them.
    """

    ACCEPT_S = 5.0
    TRACK_S = 60.0
    MAX_ATTEMPTS = 3
    RETRY_S = 2.0

    def __init__(self, channel, fs_hz: float, if_hz: float = 0.0, ready=lambda: True, sky=lambda: []):
        super().__init__(None, fs_hz, if_hz)
        self.channel, self.ready, self.sky = channel, ready, sky
        self.attempts = 1
        self._told: dict[str, object] = {"failed": None, "closed": None, "rejected": 0}

    def _unflown(self, track: ImuTrack | None) -> None:
        """An attempt not yet asked for."""
        super()._unflown(track)
        self.wanted: tuple[float, int] | None = None
        self.requested_s: float | None = None
        self.accepted_s: float | None = None
        self.maneuver_id: str | None = None
        self.vehicle_minus_sample_s = 0.0   # vehicle clock - sample clock (0: a shared clock, as in a lockstep world)
        self.failed: str | None = None
        self.failed_s: float | None = None

    def retry(self, t_s: float) -> bool:
        """After a failed attempt, RETRY_S on: a fresh one, its alarm sent at the next request. False when none is
        due (not failed, failed too recently, the link lost, or MAX_ATTEMPTS made)."""
        if self.failed_s is None or not self.ended or t_s - self.failed_s < self.RETRY_S \
                or self.attempts >= self.MAX_ATTEMPTS or getattr(self.channel, "closed", None):
            return False
        self.attempts += 1
        self._unflown(None)
        self._told["failed"] = None
        return True

    def request(self, t_s: float, prn: int) -> None:
        if self.wanted is None:
            self.wanted = (t_s, prn)
        self._poll(t_s)

    def _poll(self, t_s: float) -> None:
        if self.wanted is not None and self.requested_s is None and self.failed is None and self.ready():
            self.requested_s = t_s
            self.channel.send("alarm", {"reason": f"auxiliary peak on PRN {self.wanted[1]}", "t_s": t_s,
                                        "lines_of_sight": self.sky(), "required_spread_m": REQUIRED_SPREAD_M})
        for kind, payload in self.channel.poll():
            if kind == "maneuver_request" and self.requested_s is not None and self.accepted_s is None:
                self.accepted_s, self.maneuver_id = t_s, str(payload.get("maneuver_id", ""))[:64]
                vehicle_s = payload.get("t_s")
                if isinstance(vehicle_s, (int, float)) and not isinstance(vehicle_s, bool) and \
                        math.isfinite(vehicle_s) and abs(vehicle_s) < MAX_CLOCK_S:
                    self.vehicle_minus_sample_s = float(vehicle_s) - t_s
            elif kind == "maneuver_failed" and self.requested_s is not None and self.track is None \
                    and self.failed is None:
                why = payload.get("why")
                self.failed = ("the flight side could not fly the maneuver"
                               + (f": {why}" if isinstance(why, str) else ""))[:MAX_REASON_CHARS]
            elif kind == "maneuver_done" and self.accepted_s is not None and self.track is None:
                bound = payload.get("drift_bound_m")   # the flight side's INS error bound over its track
                if not isinstance(bound, (int, float)) or isinstance(bound, bool) or not 0.0 < bound < math.inf:
                    bound = None   # none stated (an older flight side), or not a number: the identifier's own
                elif bound > MAX_DRIFT_BOUND_M:
                    # an INS that uncertain decides no peak; taking the identifier's own 2 m instead would condemn
                    # legitimate peaks on its drift
                    self.failed = f"the IMU track's stated error bound {bound:.0f} m is too large to decide peaks"
                    continue
                try:
                    track = ImuTrack(*(np.asarray(payload[k], dtype=float)
                                       for k in ("t_s", "north_m", "east_m", "down_m")))
                    self.track = replace(track, t_s=track.t_s - self.vehicle_minus_sample_s)
                    # the flight side's track is the maneuver, start to stop: all of it is the window (the flight
                    # side drew it to move enough along every line of sight over all of it); find_maneuver, for long
                    # recordings, would cut one at a reversal's slow turn
                    self.window_s = (float(self.track.t_s[0]), float(self.track.t_s[-1]))
                    self.drift_bound_m = INS_DRIFT_M if bound is None else float(bound)
                except (KeyError, TypeError, ValueError) as exc:
                    self.failed = f"unusable IMU track ({exc})"[:MAX_REASON_CHARS]
        closed = getattr(self.channel, "closed", None)
        if self.failed is None and self.requested_s is not None and self.track is None and closed:
            # no track can come back on a lost link: waiting out TRACK_S left a closed-loop takeover on ArduCopter
            # SITL without a trusted fix for a minute after its flight side had given up
            why = f"the flight side's link is lost before the maneuver's IMU track came back: {closed}"
            self.failed = why[:MAX_REASON_CHARS]
        if self.failed is None and self.requested_s is not None:
            if self.accepted_s is None and t_s - self.requested_s > self.ACCEPT_S:
                self.failed = "the flight side did not answer the alarm"
            elif self.accepted_s is not None and self.track is None and t_s - self.accepted_s > self.TRACK_S:
                self.failed = "no IMU track came back from the maneuver"
        if self.failed is not None and self.failed_s is None:
            self.failed_s = t_s

    def news(self) -> list[tuple[str, dict]]:
        """The link lost (the flight side closed, broke its framing, or sent an oversized frame), frames rejected
        (counted: a flood is one event per REJECTS_TOLD more), the maneuver failed: each told once."""
        out = []
        closed = getattr(self.channel, "closed", None)
        if closed and closed != self._told["closed"]:
            out.append(("link_lost", {"why": f"the flight side's link is lost: {closed}"[:300]}))
            self._told["closed"] = closed
        rejected = int(getattr(self.channel, "rejected", 0) or 0)
        if rejected and (not self._told["rejected"] or rejected >= self._told["rejected"] + self.REJECTS_TOLD):
            out.append(("link_rejected", {"frames": rejected,
                                          "why": f"{rejected} frames from the flight side failed their check"}))
            self._told["rejected"] = rejected
        if self.failed and self.failed != self._told["failed"]:
            out.append(("maneuver_failed", {"why": self.failed}))
            self._told["failed"] = self.failed
        return out

    REJECTS_TOLD = 1000

    def pending(self, t_s: float) -> bool:
        """A first attempt's verdict is waited for; a retry's is not (the guesses it judges were made already)."""
        self._poll(t_s)
        return self.failed is None and not self.ended and self.attempts == 1

    def expected(self) -> bool:
        """Asked for and not over (a flight side that was never asked flies nothing)."""
        return self.wanted is not None and not self.ended

    def due_to_start(self, t_s: float) -> bool:
        self._poll(t_s)
        return self.accepted_s is not None and not self.started and self.failed is None

    def due_to_end(self, t_s: float) -> bool:
        self._poll(t_s)
        if self.ended or self.requested_s is None:
            return False
        if self.failed is not None:
            return True   # release the waiting alarms
        return self.started and self.window_s is not None and t_s >= self.window_s[1]

    def identify(self, ephemeris_of, fix) -> Identification:
        ident = super().identify(ephemeris_of, fix)
        self.channel.send("verdict", {"maneuver_id": self.maneuver_id or "", "failed": self.failed,
                                      "adversarial": any(v.adversarial for v in ident.verdicts),
                                      "peaks": [{"prn": v.prn, "peak": v.peak_id, "adversarial": v.adversarial,
                                                 "decided": v.decided} for v in ident.verdicts]})
        return ident

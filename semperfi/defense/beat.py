"""Two carriers under one correlation peak: the first sign of a seamless takeover.

A spoofer that starts aligned with the legitimate signals (code, carrier and Doppler) cannot be told apart from them
until it moves; once it drags the position at v m/s its carrier's Doppler parts from the legitimate one by up to
v / 0.19 m (42 Hz at 8 m/s), long before the two code phases part by the fraction of a chip a correlator can
resolve (10 m of drag is 0.03 chip). The tracked prompt then holds both carriers: its power beats at their Doppler
difference, as deep as twice the weaker signal's amplitude over the stronger's. One signal alone, or with the slow
fringes of a static antenna's multipath, shows no such line.

A drag's beats differ from PRN to PRN: satellite i's is (u_i . v) / lambda plus what is common to all (u_i its line
of sight). The same beat on every PRN is a relative velocity of zero -- with five lines of sight or more, (u_i . v)
equal for all of them leaves v = 0 -- a delay common to every signal: a time push, which leaves the position where
it was. Those PRNs are aligned with their twins (merged: the range within the detector's merged separation of the
legitimate one until the two part, never a good fix), not a spoofer taking the position anywhere.
"""

import numpy as np

BLOCK_MS = 5            # prompts' power averaged over 5 ms: beats up to 100 Hz stay visible
WINDOW_MS = 500         # the window each test looks at (2 Hz resolution)
MIN_BEAT_HZ = 4.0       # slower fading is the antenna's multipath or the signal's own C/N0 drift
MIN_LINE_RATIO = 30.0   # the line over the median bin: noise alone reaches 30 with probability ~1e-7 per window
MIN_DEPTH = 0.3         # the power's modulation depth: a second carrier within ~10 dB of the tracked one
BIN_HZ = 1e3 / WINDOW_MS   # a window's frequency resolution: one beat measured on two PRNs may fall a bin apart
MIN_COMMON_PRNS = 5     # lines of sight enough that one beat on all of them pins the relative velocity to zero


def beat(prompts: np.ndarray) -> tuple[float, float, float]:
    """(frequency Hz, line / median, modulation depth) of the strongest beat in 1 ms prompts' power."""
    n = prompts.size // BLOCK_MS
    power = (np.abs(prompts[:n * BLOCK_MS]) ** 2).reshape(n, BLOCK_MS).mean(axis=1)
    mean = float(power.mean())
    spectrum = np.abs(np.fft.rfft(power - mean)) ** 2
    freqs = np.fft.rfftfreq(n, BLOCK_MS * 1e-3)
    band = freqs >= MIN_BEAT_HZ
    if not band.any() or mean <= 0:
        return 0.0, 0.0, 0.0
    k = int(np.argmax(np.where(band, spectrum, -1.0)))
    median = float(np.median(spectrum[band]))
    depth = 2.0 * np.sqrt(spectrum[k]) / n / mean    # amplitude of the line over the mean power
    return float(freqs[k]), float(spectrum[k] / max(median, 1e-30)), float(depth)


def two_carriers(prompts: np.ndarray) -> float | None:
    """The beat frequency when the prompts hold two carriers, else None."""
    if prompts.size < WINDOW_MS:
        return None
    f_hz, ratio, depth = beat(prompts[-WINDOW_MS:])
    return f_hz if ratio >= MIN_LINE_RATIO and depth >= MIN_DEPTH else None


def common_beat(beats: dict[int, float], known_hz: float | None = None) -> tuple[float | None, set[int]]:
    """(the beat shared by MIN_COMMON_PRNS PRNs or more, within a bin of their median -- else known_hz, a common beat
    found before --, the PRNs within a bin of it). A PRN whose beat is further off has a spoofer moving otherwise."""
    if len(beats) >= MIN_COMMON_PRNS:
        median = float(np.median(list(beats.values())))
        near = {p for p, f in beats.items() if abs(f - median) <= BIN_HZ}
        if len(near) >= MIN_COMMON_PRNS:
            return median, near
    if known_hz is None:
        return None, set()
    return known_hz, {p for p, f in beats.items() if abs(f - known_hz) <= BIN_HZ}

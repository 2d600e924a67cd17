"""The chips' shape as the front end delivers them, measured on the spoofers' own signals.

A receiver's front end (its analog filter before sampling, a decimating filter after) passes the C/A code's main lobe
and cuts what lies beyond its band: in every real recording the code's chips are rounded and its correlation peak is
blunted. A rectangular replica subtracted from such a signal leaves what the filter changed. On GPS-SDR-SIM mixes
band-limited to +-1.3 MHz the canceller left 6-10 dB more of each spoofer than on the generator's ideal chips, and
GNSS-SDR behind the plug-in filter was pulled 10-13 m.

The received chip is modelled as the rectangular chip through a filter whose impulse response on the code's envelope
is piecewise linear, knots TAP_STEP_CHIPS apart over +-TAP_REACH_CHIPS: received = sum_k g_k b_k, b_k the code's
rectangular waveform smoothed by a triangle one knot wide and moved by knot k. That holds any front end's response
(not only a symmetric one) at any sample rate. A spoofer, the strongest signal there is, measures it: its tracked
replica's correlation with the samples at lags around it, summed coherently with its amplitudes over many code
periods, is sum_k g_k C(lag, k), C the sampled rectangular replica's overlap with each b_k -- a linear least squares
for g, over every spoofer at once. A legitimate twin within a few chips adds its own copy of the shape at its offset,
and the spoofer may sit a little off its replica (its twin pulls the tracking loop): both are fitted beside it. Ideal
chips (GPS-SDR-SIM's own rendering) are kept unless the shape explains the correlations far better than they do.
Once the shape is taken, its gains are fitted again on the samples themselves (fit_on_samples: each knot's
correlation with them, the twins as the correlations placed them), which is what a subtraction leaves: the
rectangular replica's correlations are nearly blind to what the knots hold beyond the band.

On a shape the meter also places each spoofer's twin (placed_twin), from the power its replica leaves at each lag: a
spoofer stronger than any satellite has rounded chips that look like two paths a quarter chip apart to the canceller's
two-path fit on ideal chips' model, and such a suspected twin waits for the meter to tell it from the rounding.
"""

import functools
import weakref
from dataclasses import dataclass

import numpy as np

from ..gps import CA_CODE_LENGTH_CHIPS, ca_code
from ..receiver import CodeBank, code_bank

FINE = 64                     # the shaped waveform's positions per chip (its steps of 1/64 chip: -40 dB at the edges)
TAP_STEP_CHIPS = 0.125
TAP_REACH_CHIPS = 1.0
TAPS_CHIPS = TAP_STEP_CHIPS * np.arange(-round(TAP_REACH_CHIPS / TAP_STEP_CHIPS),
                                        round(TAP_REACH_CHIPS / TAP_STEP_CHIPS) + 1)
LAGS_CHIPS = np.round(np.arange(-2.5, 2.5 + 1e-9, 0.05), 10)   # where a spoofer's correlation is measured
LAG_ZERO = int(np.argmin(np.abs(LAGS_CHIPS)))                    # the replica itself
TWIN_NEAR_CHIPS = 0.6         # a twin closer than this is told from the shape by the canceller's own fit (JOINT)
TWIN_REACH_CHIPS = 3.0        # a twin further than this barely reaches the lags: its gain is not told from noise
SPOOFER_DRIFT_CHIPS = 0.15    # how far a spoofer may sit from its replica in the fit
TWIN_MAX_GAIN = 4.0           # a twin at most this much stronger than its spoofer
TWIN_STEP_CHIPS = 0.05
TWIN_GUESS_CHIPS = 0.3        # how far from ideal chips' twin the shaped fit's is searched
MEASURED_SNR_DB = 52.0        # the spoofers' summed correlations hold this much before the shape is fitted
MEASURED_MAX_PERIODS = 3000   # or one of them was summed this long (weak spoofers: the shape fitted on less)
JUDGED_SNR_DB = 40.0          # a twin is placed on one spoofer's sums this strong
# The shape is taken when it leaves this much less of the sums than ideal chips do, and by more than noise could:
# the fit's squares are in units of each lag's noise variance, and the knots' extra gains, smooth across the lags as
# the noise is, took 480 of them from noise alone on one of our simulator's +6 dB spoofers (ideal chips), and never
# more than 28 on GPS-SDR-SIM's ideal chips (66 scenes, 3 dB to 15 dB, 2.6 and 10 MSa/s, int8 and int16). Behind
# 1 MHz the shape explained 2400-12 400 (real samples at an IF, 16 scenes), 19 000 behind 2.4 MHz: a threshold at
# 2500 kept ideal chips for two of them (2387 and 2428, -5.5 and -7.3 dB), where the rounding then passed for twins
# 0.23-0.25 chip off as strong as their spoofers, two PRNs given up on them and GNSS-SDR behind the filter no fix
SHAPED_BETTER_DB = -3.0
SHAPED_SIGNIFICANT = 1200.0
RIDGE = 1e-4                  # a little weight on the smallest response: the knots beyond the band are not seen
# and a little on the response's curvature: the rectangular replica's correlations hardly see the knots' alternating
# patterns (neighbouring knots' waveforms differ beyond the band), so a plain fit takes them from what the knots
# cannot represent -- behind 1 MHz at 2.6 MSa/s the fitted chips missed the filtered ones by -21 dB, -30 dB with this
# weight (flat from 1e-3 to 1e-2), -31 dB fitted on the samples themselves
SMOOTH = 3e-3
FIT_ROUNDS = 4
SAMPLES_RIDGE = 1e-6          # fit_on_samples: a little weight on the gains' size (the knots beyond the band)
# a spoofer whose twin followed jointly by the canceller lies closer than this measures the shape only
# when no other does: the twin shares its rounded peak, and the twin's gain and place trade against the knots (a twin
# 0.3 chip off bent the shape until the canceller's joint fit put it 0.06 chip further, its range 6 m off; the
# shape fitted on the true correlation puts it where it is)
SHAPE_APART_CHIPS = 1.0
OUTLIER_FACTOR = 5.0          # a spoofer its own shaped fit leaves this many times the usual is left out of the shape
# On a shape, each spoofer's twin is placed on it (placed_twin) where it lies TWIN_MIN_DB under the spoofer or less: the
# shape's own error lies 25-31 dB down; the noise of one spoofer's sums, JUDGED_SNR_DB strong, left 17.7 dB at most
# near it (a twin searched from SUSPECT_NEAREST_CHIPS on our own synthetic correlations), 15 dB at 32 dB. A suspected
# twin (the canceller's two-path fit on ideal chips placed it within TWIN_NEAR_CHIPS, found there 13 dB under its
# spoofer or less: DetectorConfig.two_path_min_ratio_db) is searched that near too, and kept there SUSPECT_MIN_DB
# under it or less.
TWIN_MIN_DB = 20.0
SUSPECT_MIN_DB = 13.0
SUSPECT_NEAREST_CHIPS = 0.1


@dataclass(frozen=True)
class ChipShape:
    """Gains of the knots TAPS_CHIPS (empty: rectangular chips, the code as transmitted)."""
    gains: tuple[float, ...] = ()

    @property
    def rectangular(self) -> bool:
        return not self.gains

    def correlation(self, prn: int, offset_chips):
        """What a unit signal of this shape gives the rectangular replica moved by offset_chips from it."""
        if self.rectangular:
            return code_correlation(prn, offset_chips)
        grid, values = _shaped_correlation(prn, self.gains)
        return np.interp(offset_chips, grid, values, left=0.0, right=0.0)

    def waveform(self, prn: int) -> np.ndarray:
        """The shaped code over one period, FINE values per chip (value q holds at q / FINE chips)."""
        return _waveform(prn, self.gains)

    def values(self, prn: int, positions_chips: np.ndarray) -> np.ndarray:
        """The shaped code at these positions (chips): the slow reference of what a shaped bank's rows hold."""
        wave = self.waveform(prn)
        return wave[np.floor(np.asarray(positions_chips) * FINE).astype(np.int64) % wave.size]


RECTANGULAR = ChipShape()

AUTOCORRELATION_REACH_CHIPS = 4


@functools.lru_cache(maxsize=64)
def _integer_autocorrelation(prn: int) -> np.ndarray:
    """R(k) for k = -REACH..REACH chips: the code's circular autocorrelation / 1023. At +/-1 chip it is one of
    -1, -65 or +63 / 1023 depending on the PRN: a plain triangle would bias a two-path fit by ~0.05 chip."""
    code = ca_code(prn).astype(np.float64)
    ks = np.arange(-AUTOCORRELATION_REACH_CHIPS, AUTOCORRELATION_REACH_CHIPS + 1)
    return np.array([np.dot(code, np.roll(code, k)) / code.size for k in ks])


def code_correlation(prn: int, offset_chips):
    """The code's normalised correlation with itself moved by offset_chips (rectangular chips: linear between whole
    chips); zero beyond AUTOCORRELATION_REACH_CHIPS, where only the code's sidelobes are."""
    ks = np.arange(-AUTOCORRELATION_REACH_CHIPS, AUTOCORRELATION_REACH_CHIPS + 1)
    return np.interp(offset_chips, ks, _integer_autocorrelation(prn), left=0.0, right=0.0)


def _knot_kernel() -> np.ndarray:
    """The triangle one knot wide each side, on the fine grid (unit sum): what each knot smooths the chips by."""
    half = round(TAP_STEP_CHIPS * FINE)
    tri = 1.0 - np.abs(np.arange(-half, half + 1)) / half
    return tri / tri.sum()


@functools.lru_cache(maxsize=64)
def _smoothed_autocorrelation(prn: int) -> np.ndarray:
    """code_correlation on the fine grid over +-REACH chips, smoothed by a knot's triangle (read-only)."""
    grid = np.arange(-AUTOCORRELATION_REACH_CHIPS * FINE, AUTOCORRELATION_REACH_CHIPS * FINE + 1) / FINE
    out = np.convolve(code_correlation(prn, grid), _knot_kernel(), mode="same")
    out.setflags(write=False)
    return out


@functools.lru_cache(maxsize=64)
def _shaped_correlation(prn: int, gains: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    """ChipShape.correlation on the fine grid over +-REACH chips: (offsets, values), read-only."""
    smooth = _smoothed_autocorrelation(prn)
    grid = np.arange(smooth.size) / FINE - AUTOCORRELATION_REACH_CHIPS
    values = sum(g * np.interp(grid - t, grid, smooth, left=0.0, right=0.0) for g, t in zip(gains, TAPS_CHIPS))
    values.setflags(write=False)
    return grid, values


def _fine_code(prn: int) -> np.ndarray:
    return np.repeat(ca_code(prn).astype(np.float64), FINE)


@functools.lru_cache(maxsize=32)
def _smoothed_code(prn: int) -> np.ndarray:
    """The code's rectangular waveform over one period on the fine grid, smoothed by a knot's triangle (circularly):
    b_0. Every other knot's is this moved by its tap, a whole number of fine steps (read-only, 0.5 MB)."""
    tri = _knot_kernel()
    half = tri.size // 2
    code = _fine_code(prn)
    out = sum(w * np.roll(code, k - half) for k, w in enumerate(tri) if w)
    out.setflags(write=False)
    return out


KNOT_STEPS = np.round(TAPS_CHIPS * FINE).astype(np.int64)   # each knot's move, in fine steps


@functools.lru_cache(maxsize=32)
def _waveform(prn: int, gains: tuple[float, ...]) -> np.ndarray:
    if not gains:
        out = _fine_code(prn)
    else:   # b_k(q) = b_0(q + tap_k): moved ahead by the tap
        smooth = _smoothed_code(prn)
        out = sum(g * np.roll(smooth, -int(m)) for g, m in zip(gains, KNOT_STEPS))
    out.setflags(write=False)
    return out


def knot_values(prn: int, positions_chips: np.ndarray) -> np.ndarray:
    """Every b_k at these positions (knots, positions)."""
    smooth = _smoothed_code(prn)
    q = np.floor(np.asarray(positions_chips) * FINE).astype(np.int64)
    return smooth[(q[None, :] + KNOT_STEPS[:, None]) % smooth.size]


_BANKS: "weakref.WeakValueDictionary[tuple, CodeBank]" = weakref.WeakValueDictionary()


def shaped_bank(prn: int, fs_hz: float, shape: ChipShape, place_chips: float = 0.0) -> CodeBank:
    """The PRN's code bank with the shape's chips (int8, its largest value 127: within 0.4 % of the shape's peak),
    the code place_chips ahead of the replica's (a spoofer that sits there): what a subtraction reads. The rectangular
    shape's is the tracking bank itself."""
    bank = code_bank(prn, fs_hz)
    if shape.rectangular:
        return bank
    key = (prn, fs_hz, shape, place_chips)
    out = _BANKS.get(key)
    if out is None:
        phases, columns = bank.rows.shape
        positions = (np.arange(columns)[None, :] - bank.first + np.arange(phases)[:, None] / phases) * bank.step_chips \
            + place_chips
        scale = 127.0 / float(np.max(np.abs(shape.waveform(prn))))
        rows = np.round(shape.values(prn, positions) * scale).astype(np.int8)
        rows.flags.writeable = False
        out = _BANKS[key] = CodeBank(rows, bank.first, bank.step_chips, scale)
    return out


@dataclass
class _Seen:
    """One spoofer's correlations, summed: S(lag) = sum_b Re(y_b(lag) conj(a_b)), E = sum_b |a_b|^2."""
    s: np.ndarray
    energy: float
    noise: float              # sum_b |a_b|^2 x the variance of one period's correlation
    overlap: np.ndarray       # C (lags, knots), from one of its periods
    rectangular: np.ndarray   # (lags): the same for rectangular chips
    twin_chips: float | None  # a twin the canceller already fits jointly (its offset), else searched
    suspect_chips: float | None = None   # a twin the canceller holds back until the shape is known (its offset)
    # over neighbouring periods b, b+1 (placed_twin): sum Re(y_b conj(y_b+1)), sum Re(a_b conj(y_b+1) + y_b conj(a_b+1))
    # per lag, and sum Re(a_b conj(a_b+1))
    next_yy: np.ndarray | float = 0.0
    next_ay: np.ndarray | float = 0.0
    next_aa: float = 0.0
    periods: int = 0
    knots: np.ndarray | float = 0.0   # K_k = sum_b Re(k_b,k conj(a_b)): the samples' correlations with each knot's b_k
    visits: np.ndarray | float = 0.0  # per fine step of the code's period: sum_b |a_b|^2 / n_b x its samples there


# b_0 alone: read at lag TAPS_CHIPS[k], its bank gives each knot's b_k (the samples' correlations with the knots)
KNOT_SHAPE = ChipShape(tuple(float(t == 0.0) for t in TAPS_CHIPS))


def knot_bank(prn: int, fs_hz: float) -> CodeBank:
    """The bank that reads the samples' correlations with every knot: correlator_bank(..., knot_bank, TAPS_CHIPS)."""
    return shaped_bank(prn, fs_hz, KNOT_SHAPE)


def fine_visits(blocks: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Per fine step of the code's period: each period's weight / its samples, times its samples that fall there
    (blocks: first, n, code phase, chips per sample, ... per period, as tracking placed them)."""
    counts = blocks[:, 1].astype(np.int64)
    period = np.repeat(np.arange(len(blocks)), counts)
    k = np.arange(period.size) - np.repeat(np.cumsum(counts) - counts, counts)
    q = np.floor((blocks[period, 2] + k * blocks[period, 3]) * FINE).astype(np.int64) % (CA_CODE_LENGTH_CHIPS * FINE)
    return np.bincount(q, weights=(weights / counts)[period], minlength=CA_CODE_LENGTH_CHIPS * FINE)


def knot_gram(prn: int, visits: np.ndarray, offset_chips: float = 0.0) -> np.ndarray:
    """(knots, knots): sum_n b_k(pos_n) b_l(pos_n + offset_chips) over the samples fine_visits counted, each as it
    weighed them: what a signal through the knots' gains, moved by the offset (to a fine step), gives each knot's
    correlation. Exact for the samples themselves: one period's positions stood in for all missed the chips a
    -30 dB fit reaches by -24 dB."""
    b = _smoothed_code(prn)
    q = np.arange(b.size)[:, None]
    here = b[(q + KNOT_STEPS[None, :]) % b.size]
    moved = here if not offset_chips else b[(q + KNOT_STEPS[None, :] + round(offset_chips * FINE)) % b.size]
    return here.T @ (visits[:, None] * moved)


def overlap_matrix(prn: int, block: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """C[lag, k]: the rectangular replica moved by each of LAGS_CHIPS times b_k, over one code period's samples as
    tracking placed them (block: first, n, code phase, chips per sample, ...), / samples; and the same for the
    rectangular replica itself (what ideal chips give)."""
    n, cp, step = int(block[1]), float(block[2]), float(block[3])
    pos = cp + np.arange(n) * step
    code = ca_code(prn).astype(np.float32)
    rect = code[np.floor(pos[None, :] + LAGS_CHIPS[:, None]).astype(np.int64) % CA_CODE_LENGTH_CHIPS]
    b = knot_values(prn, pos).astype(np.float32)
    at_zero = rect[LAG_ZERO]
    return (rect @ b.T).astype(np.float64) / n, (rect @ at_zero).astype(np.float64) / n


class ChipShapeMeter:
    """Sums the spoofers' correlations until they hold MEASURED_SNR_DB, then fits the shape once (shape: rectangular
    until then, and after when the fit says so)."""

    def __init__(self):
        self.shape = RECTANGULAR
        self.done = False
        self.distance_db: float | None = None   # the fitted shape's distance from rectangular chips
        self.explained_db: float | None = None  # what it leaves of the sums, against what ideal chips leave
        self.explained: float | None = None     # the same as a difference, in units of the noise
        # each spoofer measured: its twin on the decided shape (offset from the spoofer, chips; dB under it), or None
        self.twins: dict[int, tuple[float, float] | None] = {}
        self.place_chips = 0.0   # where the spoofers sit from their replicas on this shape (the canceller's vote)
        self._model, self._gains = _RectangularModel(), np.ones(1)   # decided
        self._seen: dict[int, _Seen] = {}

    def add(self, prn: int, y: np.ndarray, knots: np.ndarray | None, amplitudes: np.ndarray, noise_power: float,
            blocks: np.ndarray, twin_chips: float | None, suspect_chips: float | None = None) -> None:
        """A spoofer's bank over LAGS_CHIPS (periods, lags) on samples it is not yet subtracted from, the same
        samples' correlations with each knot's b_k (periods, knots: knot_bank read at TAPS_CHIPS; None once the shape
        is decided, a suspect's twin still summed), and its amplitude per period (the correlation at lag 0 / samples),
        over its periods as tracking placed them (blocks)."""
        ok = np.isfinite(y).all(axis=1) & np.isfinite(amplitudes)
        if knots is not None:
            ok &= np.isfinite(knots).all(axis=1)
        if (self.done and suspect_chips is None) or not ok.any():
            return
        a = amplitudes[ok]
        s = np.real(y[ok].T @ np.conj(a))
        energy = float(np.sum(np.abs(a) ** 2))
        seen = self._seen.get(prn)
        if seen is None:
            seen = self._seen[prn] = _Seen(np.zeros(LAGS_CHIPS.size), 0.0, 0.0,
                                           *overlap_matrix(prn, blocks[len(blocks) // 2]), twin_chips)
        seen.s += s
        if knots is not None:
            seen.knots = seen.knots + np.real(knots[ok].T @ np.conj(a))
            seen.visits = seen.visits + fine_visits(blocks[ok], np.abs(a) ** 2)
        seen.energy += energy
        seen.noise += energy * noise_power
        pairs = ok[:-1] & ok[1:]
        y0, y1, a0, a1 = y[:-1][pairs], y[1:][pairs], amplitudes[:-1][pairs], amplitudes[1:][pairs]
        seen.next_yy = seen.next_yy + np.sum(np.real(y0 * np.conj(y1)), axis=0)
        seen.next_ay = seen.next_ay + np.sum(np.real(a0[:, None] * np.conj(y1) + y0 * np.conj(a1)[:, None]), axis=0)
        seen.next_aa += float(np.sum(np.real(a0 * np.conj(a1))))
        seen.periods += int(ok.sum())
        seen.twin_chips, seen.suspect_chips = twin_chips, suspect_chips

    def as_event(self) -> dict:
        """What was decided, for the events: the shape, and how the fit told it from ideal chips."""
        out = {"shape": "rectangular" if self.shape.rectangular else "shaped"}
        if self.explained_db is not None:
            out |= {"explained_db": round(self.explained_db, 1), "explained": round(float(self.explained), 1),
                    "distance_db": round(float(self.distance_db), 1)}
        if not self.shape.rectangular:
            out |= {"taps_chips": [round(float(t), 4) for t in TAPS_CHIPS],
                    "gains": [round(g, 4) for g in self.shape.gains],
                    "twins": {str(prn): _twin_event(t) for prn, t in sorted(self.twins.items())}}
        return out

    @property
    def snr_db(self) -> float:
        """What the sums hold: each spoofer's E^2 / noise, summed (the inverse variance of the fitted shape)."""
        total = sum(v.energy ** 2 / v.noise for v in self._seen.values() if v.noise > 0)
        return float(10 * np.log10(total)) if total > 0 else -np.inf

    def fit_when_ready(self) -> dict[int, tuple[float, float] | None]:
        """Fits the shape once the sums hold MEASURED_SNR_DB (or one spoofer was summed MEASURED_MAX_PERIODS), and
        on a shape places the twins of the spoofers summed to JUDGED_SNR_DB; after, those of the suspects still
        summed. Returns the twins just judged (also in self.twins): PRN -> (offset from the spoofer, chips; dB under
        it) or None; a suspect on ideal chips, or too weak to tell after MEASURED_MAX_PERIODS, as the canceller's
        two-path fit placed it (dB: nan)."""
        judged: dict[int, tuple[float, float] | None] = {}
        if not self.done:
            if self.snr_db < MEASURED_SNR_DB and max((v.periods for v in self._seen.values()), default=0) < \
                    MEASURED_MAX_PERIODS:
                return judged
            self.done = True
            items = {prn: v for prn, v in self._seen.items() if v.energy > 0 and v.noise > 0}
            self._seen = {prn: v for prn, v in items.items() if v.suspect_chips is not None}   # go on being summed
            if not items:
                return judged
            self._model, self._gains = self._decide(list(items.items()))
            if not self.shape.rectangular:
                judged = {prn: placed_twin(prn, v, self._gains, self._model) for prn, v in items.items()
                          if _snr_db(v) >= JUDGED_SNR_DB}
        for prn, v in list(self._seen.items()):
            weak = _snr_db(v) < JUDGED_SNR_DB
            if prn not in judged and (self.shape.rectangular or (weak and v.periods >= MEASURED_MAX_PERIODS)):
                judged[prn] = (float(v.suspect_chips), float("nan"))
            elif prn not in judged and not weak:
                judged[prn] = placed_twin(prn, v, self._gains, self._model)
            if prn in judged:
                del self._seen[prn]
        self.twins.update(judged)
        return judged

    def _decide(self, items: list) -> tuple:
        """The shape from every spoofer's sums (self.shape), and the model and gains decided."""
        # each spoofer alone first, ideal chips' twins first (their one gain cannot bend to a twin in the wrong place,
        # as the knots' can); then the knots over the spoofers they fit alike: one whose twin sits where the shape is
        # (GPS-SDR-SIM, 1 km, a joint track 0.6 chip off) would bend the front end to it
        rectangular = {prn: fit_gains([(prn, v)], _RectangularModel()) for prn, v in items}
        twins = {prn: fit[2][prn] for prn, fit in rectangular.items()}
        alone = {prn: fit_gains([(prn, v)], _ShapedModel(), twins)[1] for prn, v in items}
        usual = OUTLIER_FACTOR * max(float(np.median(list(alone.values()))), LAGS_CHIPS.size)
        items = [(prn, v) for prn, v in items if alone[prn] <= usual]
        items = [(prn, v) for prn, v in items if not _twin_within(v, SHAPE_APART_CHIPS)] or items
        rectangular_left = sum(rectangular[prn][1] for prn, _ in items)
        gains, shaped_left, shaped_twins = fit_gains(items, _ShapedModel(), twins)
        self.explained_db = float(10 * np.log10(max(shaped_left, 1e-30) / max(rectangular_left, 1e-30)))
        self.explained = rectangular_left - shaped_left
        shaped = self.explained_db < SHAPED_BETTER_DB and self.explained > SHAPED_SIGNIFICANT
        if shaped:
            gains = fit_on_samples(items, gains, shaped_twins)
        self.distance_db = rectangular_distance_db(gains)
        if not shaped:
            return _RectangularModel(), np.ones(1)
        self.shape = ChipShape(tuple(float(g) for g in gains))
        return _ShapedModel(), gains


def _twin_within(v: _Seen, chips: float) -> bool:
    """Whether a spoofer's twin followed jointly lies within `chips` of it (a suspect is not counted: under a
    spoofer stronger than any satellite it is mostly the rounding itself, and leaving those spoofers out measured
    the shape on the few whose twins no one had seen -- GPS-SDR-SIM behind 1 MHz, flying, 500 m, +15 dB: GNSS-SDR
    behind the filter 20 -> 368 m)."""
    return v.twin_chips is not None and abs(v.twin_chips) < chips


def _twin_event(twin: tuple[float, float] | None) -> list | None:
    """A judged twin for the events: [chips from the spoofer, dB under it (None: as the two-path fit placed it)]."""
    if twin is None:
        return None
    return [round(twin[0], 3), None if np.isnan(twin[1]) else round(twin[1], 1)]


def _snr_db(v: _Seen) -> float:
    return float(10 * np.log10(v.energy ** 2 / v.noise)) if v.energy > 0 and v.noise > 0 else -np.inf


def rectangular_distance_db(gains: np.ndarray) -> float:
    """How far a shape is from rectangular chips: the mean square of their difference, over any PRN's period."""
    wave = _waveform(1, tuple(float(g) for g in gains))
    return float(10 * np.log10(max(np.mean((wave - _fine_code(1)) ** 2), 1e-30)))


class _ShapedModel:
    """Correlations as the knots give them."""
    def columns(self, v: _Seen) -> np.ndarray:
        return v.overlap

    def twin(self, prn: int, d: float) -> np.ndarray:
        """(lags, knots): a unit twin d chips from the spoofer, through each knot (the continuous correlation)."""
        smooth = _smoothed_autocorrelation(prn)
        grid = np.arange(smooth.size) / FINE - AUTOCORRELATION_REACH_CHIPS
        return np.interp(LAGS_CHIPS[:, None] - d - TAPS_CHIPS[None, :], grid, smooth, left=0.0, right=0.0)

    def twin_response(self, prn: int, gains: np.ndarray):
        """d -> twin(prn, d) @ gains, from one table of the shape's correlation (a twin's search tries ~100 d)."""
        grid, values = _shaped_correlation(prn, tuple(float(g) for g in gains))
        return lambda d: np.interp(LAGS_CHIPS - d, grid, values, left=0.0, right=0.0)

    def start(self) -> np.ndarray:
        gains = np.zeros(TAPS_CHIPS.size)
        gains[TAPS_CHIPS.size // 2] = 1.0
        return gains


class _RectangularModel:
    """Correlations as ideal chips give them (one gain)."""
    def columns(self, v: _Seen) -> np.ndarray:
        return v.rectangular[:, None]

    def twin(self, prn: int, d: float) -> np.ndarray:
        return code_correlation(prn, LAGS_CHIPS - d)[:, None]

    def twin_response(self, prn: int, gains: np.ndarray):
        return lambda d: gains[0] * code_correlation(prn, LAGS_CHIPS - d)

    def start(self) -> np.ndarray:
        return np.ones(1)


def _moved(columns: np.ndarray, s: float) -> np.ndarray:
    """Correlations over the lags (rows) of a signal s chips further from the replica (interpolated)."""
    if not s:
        return columns
    return np.stack([np.interp(LAGS_CHIPS - s, LAGS_CHIPS, col) for col in columns.T], axis=1)


def fit_gains(items: list, model, twins: dict[int, tuple[float, float]] | None = None
              ) -> tuple[np.ndarray, float, dict[int, tuple[float, float]]]:
    """A model's gains from every spoofer's sums (least squares weighted by their SNR), normalised so a signal's
    correlation at the replica is its amplitude, as tracking measures it; the weighted squares the fit leaves, and
    each spoofer's twin (offset, gain). Beside each spoofer: its twin, searched near `twins` (another model's) when
    given, and where the spoofer itself sits from its replica (a twin a chip or two off pulls a tracking loop's
    early-late balance by hundredths of a chip once the chips are rounded)."""
    gains = model.start()
    guesses = dict(twins or {})
    where = {prn: 0.0 for prn, _ in items}
    twins = {prn: _best_twin(prn, v, gains, model, guesses.get(prn)) for prn, v in items}
    left = np.inf
    for _ in range(FIT_ROUNDS):
        rows, rhs = [], []
        for prn, v in items:
            d, c = twins[prn]
            w = np.sqrt(v.energy ** 2 / v.noise)
            rows.append(w * (_moved(model.columns(v), where[prn]) + (c * model.twin(prn, d) if c else 0.0)))
            rhs.append(w * v.s / v.energy)   # (the noise's own share, sigma^2 / (|a|^2 + sigma^2), under 2 % at +3 dB)
        a, b = np.vstack(rows), np.concatenate(rhs)
        gains = np.linalg.solve(a.T @ a + _prior(a), a.T @ b)
        left = float(np.sum((a @ gains - b) ** 2))
        for prn, v in items:
            where[prn] = _best_place(prn, v, gains, model, twins[prn])
            twins[prn] = _best_twin(prn, v, gains, model, guesses.get(prn), where[prn])
    at_zero = np.mean([model.columns(v)[LAG_ZERO, :] for _, v in items], axis=0)
    return gains / float(at_zero @ gains), left, twins


def fit_on_samples(items: list, gains: np.ndarray, twins: dict[int, tuple[float, float]]) -> np.ndarray:
    """The knots' gains by least squares over the spoofers' samples themselves, what a subtraction leaves (from
    their correlations with each knot: sum_b K_b = E G g), each spoofer's twin (offset, gain from the correlations'
    fit) taken out as the gains being fitted put it; normalised as fit_gains. The replica's correlations see the
    chips only through rectangular chips' overlaps, blind to what the knots hold beyond the band: fitted on them, a
    +6 dB spoofer's chips behind 1 MHz were missed by -25.2 dB, on its samples by -30.6 dB (-32.1 dB noise-free)."""
    lhs = sum(knot_gram(prn, v.visits) for prn, v in items)
    lhs = lhs + SAMPLES_RIDGE * float(np.trace(lhs)) / lhs.shape[0] * np.eye(lhs.shape[0])
    crossed = {prn: twins[prn][1] * knot_gram(prn, v.visits, twins[prn][0])
               for prn, v in items if twins.get(prn, (0.0, 0.0))[1]}
    for _ in range(FIT_ROUNDS if crossed else 1):
        rhs = sum(v.knots - (crossed[prn] @ gains if prn in crossed else 0.0) for prn, v in items)
        gains = np.linalg.solve(lhs, rhs)
    at_zero = np.mean([v.overlap[LAG_ZERO, :] for _, v in items], axis=0)
    return gains / float(at_zero @ gains)


def _prior(a: np.ndarray) -> np.ndarray:
    """The fit's weights on the gains' size (RIDGE) and curvature (SMOOTH, over three knots or more), in units of
    the columns' mean square."""
    size = float(np.sum(a ** 2)) / a.shape[1]
    out = RIDGE * size * np.eye(a.shape[1])
    if a.shape[1] >= 3:
        curve = np.diff(np.eye(a.shape[1]), 2, axis=0)
        out += SMOOTH * size * curve.T @ curve
    return out


def _best_place(prn: int, v: _Seen, gains: np.ndarray, model, twin: tuple[float, float]) -> float:
    """Where the spoofer sits from its replica (within SPOOFER_DRIFT_CHIPS), given the shape and its twin."""
    d, c = twin
    own = model.columns(v) @ gains
    want = v.s / v.energy - (c * model.twin_response(prn, gains)(d) if c else 0.0)
    places = np.arange(-SPOOFER_DRIFT_CHIPS, SPOOFER_DRIFT_CHIPS + 1e-9, 0.005)
    misfit = [float(np.sum((np.interp(LAGS_CHIPS - s, LAGS_CHIPS, own) - want) ** 2)) for s in places]
    return float(places[int(np.argmin(misfit))])


def placed_twin(prn: int, v: _Seen, gains: np.ndarray, model) -> tuple[float, float] | None:
    """A spoofer's twin on the decided model, (offset from the spoofer, chips; power under it, dB), when TWIN_MIN_DB
    strong or more, from what the spoofer's replica leaves at each lag, r_b = y_b - a_b m (m the spoofer's
    correlation on the model, fitted with its place and its phase-locked twin). A twin t_b at offset d leaves
    t_b (T(lag - d) - T(-d) m) (T its correlation, its share of a_b taken out with the spoofer's), whatever its phase
    and Doppler against the spoofer. Taken over neighbouring periods, Re(r_b conj(r_b+1)) holds the twin's power,
    turned by a few hundredths of a radian, and no noise (each period's is its own; in r_b r_b* it would be there,
    correlated between the lags as a front end shapes it), normalised by the same product of the spoofer's
    amplitudes (a bit's edge turns both alike). A suspected twin is searched from SUSPECT_NEAREST_CHIPS out."""
    nearest = SUSPECT_NEAREST_CHIPS if v.suspect_chips is not None else TWIN_NEAR_CHIPS
    place, twin = 0.0, (0.0, 0.0)
    for _ in range(FIT_ROUNDS):
        twin = _best_twin(prn, v, gains, model, place=place, nearest=nearest)
        place = _best_place(prn, v, gains, model, twin)
    m = _moved(model.columns(v) @ gains[:, None], place)[:, 0]
    if not v.next_aa > 0:
        return None
    left = (v.next_yy - m * v.next_ay + m * m * v.next_aa) / v.next_aa
    side = np.arange(nearest, TWIN_REACH_CHIPS + 1e-9, TWIN_STEP_CHIPS)
    response = model.twin_response(prn, gains)
    best, found = 0.0, None
    for d in np.concatenate([-side[::-1], side]) + place:
        t = response(d)
        u2 = (t - t[LAG_ZERO] * m) ** 2
        weight = float(u2 @ u2)
        if weight <= 0:
            continue
        p = float(u2 @ left) / weight
        if p > 0 and p * p * weight > best:
            best, found = p * p * weight, (float(d - place), p)
    if found is None:
        return None
    floor_db = SUSPECT_MIN_DB if abs(found[0]) < TWIN_NEAR_CHIPS else TWIN_MIN_DB
    if found[1] < 10 ** (-floor_db / 10):
        return None
    return found[0], float(-10 * np.log10(found[1]))


def _best_twin(prn: int, v: _Seen, gains: np.ndarray, model, guess: tuple[float, float] | None = None,
               place: float = 0.0, nearest: float = TWIN_NEAR_CHIPS) -> tuple[float, float]:
    """The twin's (offset, gain) that best explains what the model leaves of this spoofer's sums (the spoofer
    `place` chips from its replica), near the canceller's own twin or a guess when there is one; (0, 0) when none
    explains anything."""
    left = v.s / v.energy - _moved(model.columns(v) @ gains[:, None], place)[:, 0]
    if v.twin_chips is not None and abs(v.twin_chips) < TWIN_REACH_CHIPS:
        candidates = v.twin_chips + np.arange(-0.1, 0.1 + 1e-9, 0.01)
    elif guess is not None and guess[1]:
        candidates = guess[0] + np.arange(-TWIN_GUESS_CHIPS, TWIN_GUESS_CHIPS + 1e-9, 0.01)
    else:
        side = np.arange(nearest, TWIN_REACH_CHIPS + 1e-9, TWIN_STEP_CHIPS)
        candidates = np.concatenate([-side[::-1], side])
    best, arg = 0.0, (0.0, 0.0)
    response = model.twin_response(prn, gains)
    for d in candidates:
        col = response(d)
        power = float(col @ col)
        if power <= 0:
            continue
        c = float(col @ left) / power
        if abs(c) <= TWIN_MAX_GAIN and c * c * power > best:
            best, arg = c * c * power, (float(d), c)
    return arg

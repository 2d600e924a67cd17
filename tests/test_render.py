"""The numba rendering kernel against its plain numpy reference."""

import numpy as np

from semperfi.gps.codes import ca_code
from semperfi.sim.render import render, render_reference


def test_kernel_equals_reference():
    rng = np.random.default_rng(3)
    n, n_sig = 20000, 5
    codes = np.stack([ca_code(p) for p in (1, 5, 9, 17, 31)])
    bits = rng.choice(np.array([-1, 1], dtype=np.int8), size=(n_sig, 4))
    chips0 = rng.uniform(0, 20460, n_sig)
    chip_rate = 1.023e6 / 4e6 * (1 + rng.uniform(-3e-6, 3e-6, n_sig))
    phase0 = rng.uniform(0, 1, n_sig)
    phase_rate = rng.uniform(-4000, 4000, n_sig) / 4e6
    amp = rng.uniform(0.1, 2.0, n_sig)
    amp[2] = 0.0
    out = np.zeros(n, dtype=np.complex64)
    render(out, codes, bits, chips0, chip_rate, phase0, phase_rate, amp)
    ref = render_reference(n, codes, bits, chips0, chip_rate, phase0, phase_rate, amp)
    # the kernel's carrier table has 4096 entries: phase error below pi/4096
    err = np.abs(out - ref)
    assert np.max(err) < np.sum(amp) * np.pi / 4096 * 1.01 + 1e-5, np.max(err)
    # and the chips and bits are the same everywhere: the sign pattern of the real part agrees
    assert np.mean(np.sign(out.real) == np.sign(ref.real)) > 0.999

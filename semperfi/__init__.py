"""SemperFi: a spoofer-eliminating GPS L1 C/A software receiver, and the world it is proven against."""

import numpy  # noqa: F401  (loads BLAS, which threadpool_limits can only limit once loaded)
from threadpoolctl import threadpool_limits

__version__ = "0.1.0"

# Every matrix here is small (a fix's geometry, a two-path Gram of 81 x 81): BLAS threads only wake, spin and
# contend with the receiver's own threads (measured: 2.4 s of CPU per 12 s of signal on a busy 2-core machine).
threadpool_limits(limits=1, user_api="blas")

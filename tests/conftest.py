"""One BLAS thread per test process, set before numpy loads (here, as pytest starts).

``make test`` runs the suite on two workers (pytest-xdist, ``-n 2``); a multithreaded BLAS in each would put four
or more busy threads on two cores, and the identification's tall SVDs wait for each other (many times slower on a
loaded machine). Commands the tests start inherit it. A value already in the environment is kept.
"""

from __future__ import annotations

import os

for _name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

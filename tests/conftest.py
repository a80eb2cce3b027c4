"""The environment every test runs in, set as pytest starts (before numpy loads).

One BLAS thread per test process: ``make test`` runs the suite on two workers (pytest-xdist, ``-n 2``); a
multithreaded BLAS in each would put four or more busy threads on two cores, and the identification's tall SVDs
wait for each other (many times slower on a loaded machine). Commands the tests start inherit it. A value already
in the environment is kept.

No terminal size: the commands' output goes to pipes and buffers here, which is not wrapped (common/fit_width.py);
an xdist worker inherits ``COLUMNS=80``/``LINES=24`` that GNU readline exports, which would wrap it. A test of the
wrapped output sets ``COLUMNS`` itself.
"""

from __future__ import annotations

import os

for _name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

for _name in ("COLUMNS", "LINES"):
    os.environ.pop(_name, None)

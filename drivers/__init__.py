"""Devices. At the top, the contract every backend implements and shares: protocols and readings (``base``), errors,
device strings (``spec``), the backend registry that imports a backend only when it is opened (``registry``),
clocks, motion timing, byte traces, averaging and the stream buffer. One subpackage per device family: ``ur``
(``ur5e@HOST``), ``trackers`` (``serial:PORT``, ``ipp://HOST``, ``emscon:HOST``), ``camera`` (``aruco:SOURCE``), ``sim``
(``mock:MODEL``, ``mock``)."""

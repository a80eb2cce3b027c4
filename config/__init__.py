"""Configuration as data: robot models (``robots/*.yaml``), tracker profiles (``trackers/*.yaml``), the site file,
and the code that loads and validates them (``files``: reading and errors; ``robots``, ``geometry``, ``site`` and its
value checks ``site_checks``)."""

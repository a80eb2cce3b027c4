"""Trackers that report 3D points: ``serial:PORT?protocol=NAME`` (line-oriented ASCII devices over pyserial, driven
by a profile: ``serial_tracker``, ``ascii_profile``, ``serial_stream``) and ``ipp://HOST[:PORT]`` (I++ DME over TCP:
``ipp``, ``ipp_protocol``, ``ipp_stream``) and ``emscon:HOST[:PORT]`` (Leica laser trackers through the emScon TPI,
binary packets over TCP: ``emscon``, ``emscon_protocol``, ``emscon_options``, ``emscon_stream`` (continuous
measurement), ``emscon_probe`` (6-DoF probe poses), and ``emscon_sim``, the simulated server of ``emscon:sim``);
``socket_reads`` is the TCP clients' read and the simulated servers' accept loop. ``serial`` is imported only when a
serial tracker is opened."""

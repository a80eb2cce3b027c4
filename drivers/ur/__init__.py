"""Universal Robots arms, spec ``ur5e@HOST`` (or ``ur:MODEL@HOST``): RTDE through ``ur_rtde`` in a worker process
(``driver``, ``worker``; what the controller's robot and safety modes mean: ``modes``), the joint stream of
continuous motion (``stream``, ``recorder``) and what the controller says outside RTDE (``info``: dashboard
server, factory calibration). ``ur_rtde`` is imported only when a robot is opened."""

"""The simulated rig of mock mode, specs ``mock:MODEL`` (robot) and ``mock`` (tracker): one simulated world
(``rig``, ``world``, ``pairing``) seen by a simulated robot (``robot``) and tracker (``tracker``), with their
streams (``stream``; their settings and a move on the clock: ``stream_model``)."""

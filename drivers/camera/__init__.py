"""A camera tracker, spec ``aruco:SOURCE?camera=FILE...``: ArUco targets seen by OpenCV (``tracker``, ``targets``,
``refinement``, ``pose``), camera intrinsics (``intrinsics``), frame sources (``sources``), rendered images of the
simulated rig (``renderer``) and the stream at the frame rate (``stream``). ``cv2`` is imported only when a camera
is opened."""
